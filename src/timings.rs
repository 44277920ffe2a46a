//! Where a deblur's time goes: each stage's time summed over every thread that ran it
//! (so parallel stages add up to more than the wall clock), the wall clock of the whole
//! deblur, and how many tiles were solved. A deblur fills one when its job carries one
//! ([`crate::job::JobContext::with_timings`]); without one, timing costs a branch per
//! stage and reads no clock.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// A stage of the deblur.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The tile grid: the kernels probed over each plane to size the margins.
    Grid,
    /// Each tile's kernel: the source's prediction at the tile centre, at plane
    /// resolution, cropped to the block's margin.
    Kernels,
    /// Each tile's kernel spectrum (the kernel wrapped into the block, transformed).
    Spectra,
    /// Block FFTs, forward and inverse (those of the spectra excepted).
    ForwardFft,
    InverseFft,
    /// The edge taper's blend toward the circularly blurred block (its FFTs apart).
    Taper,
    /// The solver's own passes between its FFTs: HQS's shrinkage and divergence and its
    /// Fourier-domain update; Wiener's and IRLS's products.
    Solve,
    /// Blocks read from the plane (reflected past its border) and, on the GPU, the
    /// planes made ready for upload.
    Convert,
    /// Each tile's window weighted and summed into the output plane.
    Blend,
    /// Colour fringes held back, and the amount applied.
    Finish,
    /// GPU: buffers made and written (planes, kernels, tables).
    Upload,
    /// GPU: the recorded passes submitted and waited for.
    Gpu,
    /// GPU: the result mapped and copied back.
    Readback,
}

impl Stage {
    pub const ALL: [Stage; 13] = [
        Stage::Grid,
        Stage::Kernels,
        Stage::Spectra,
        Stage::ForwardFft,
        Stage::InverseFft,
        Stage::Taper,
        Stage::Solve,
        Stage::Convert,
        Stage::Blend,
        Stage::Finish,
        Stage::Upload,
        Stage::Gpu,
        Stage::Readback,
    ];

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Stage::Grid => "tile grid",
            Stage::Kernels => "kernel prediction",
            Stage::Spectra => "kernel spectra",
            Stage::ForwardFft => "forward FFTs",
            Stage::InverseFft => "inverse FFTs",
            Stage::Taper => "edge taper",
            Stage::Solve => "solver passes",
            Stage::Convert => "plane conversion",
            Stage::Blend => "blend",
            Stage::Finish => "fringes, amount",
            Stage::Upload => "upload",
            Stage::Gpu => "GPU passes",
            Stage::Readback => "readback",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

const STAGES: usize = Stage::ALL.len();

/// A deblur's stage times, shared by the threads that fill it.
#[derive(Debug, Default)]
pub struct Timings {
    nanos: [AtomicU64; STAGES],
    wall: AtomicU64,
    tiles: AtomicU64,
    /// GPU: bytes written to the device, all of them and those of the tiles' kernels.
    uploaded: AtomicU64,
    kernel_bytes: AtomicU64,
}

impl Timings {
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    pub fn add(&self, stage: Stage, d: Duration) {
        self.nanos[stage.index()].fetch_add(nanos(d), Ordering::Relaxed);
    }

    /// Adds what a thread's [`Clock`] gathered, and empties it.
    pub fn absorb(&self, clock: &mut Clock) {
        for (total, n) in self.nanos.iter().zip(&mut clock.nanos) {
            if *n > 0 {
                total.fetch_add(*n, Ordering::Relaxed);
                *n = 0;
            }
        }
        self.tiles.fetch_add(clock.tiles, Ordering::Relaxed);
        clock.tiles = 0;
    }

    pub fn add_wall(&self, d: Duration) {
        self.wall.fetch_add(nanos(d), Ordering::Relaxed);
    }

    pub fn add_tiles(&self, n: usize) {
        self.tiles.fetch_add(n as u64, Ordering::Relaxed);
    }

    /// Counts an upload to the GPU: `bytes` in all, `kernels` of them the tiles' kernels.
    pub fn add_upload(&self, bytes: u64, kernels: u64) {
        self.uploaded.fetch_add(bytes, Ordering::Relaxed);
        self.kernel_bytes.fetch_add(kernels, Ordering::Relaxed);
    }

    /// Bytes uploaded to the GPU: (all, the tiles' kernels).
    #[must_use]
    pub fn uploaded(&self) -> (u64, u64) {
        (
            self.uploaded.load(Ordering::Relaxed),
            self.kernel_bytes.load(Ordering::Relaxed),
        )
    }

    /// Seconds summed over threads.
    #[must_use]
    pub fn seconds(&self, stage: Stage) -> f64 {
        self.nanos[stage.index()].load(Ordering::Relaxed) as f64 * 1e-9
    }

    #[must_use]
    pub fn wall_seconds(&self) -> f64 {
        self.wall.load(Ordering::Relaxed) as f64 * 1e-9
    }

    #[must_use]
    pub fn tiles(&self) -> u64 {
        self.tiles.load(Ordering::Relaxed)
    }

    /// Starts the clock on `stage` when there is one: `None` reads no clock.
    #[must_use]
    pub fn start(this: Option<&Self>) -> Option<Instant> {
        this.map(|_| Instant::now())
    }

    /// Adds the time since `started` (from [`Self::start`]) to `stage`.
    pub fn stop(this: Option<&Self>, stage: Stage, started: Option<Instant>) {
        if let (Some(t), Some(s)) = (this, started) {
            t.add(stage, s.elapsed());
        }
    }

    /// A table: each stage that took time, its thread-seconds and share, the wall clock.
    #[must_use]
    pub fn table(&self) -> String {
        use std::fmt::Write;
        let total: f64 = Stage::ALL.iter().map(|&s| self.seconds(s)).sum();
        let mut out = String::new();
        let _ = writeln!(out, "{:<20} {:>10} {:>7}", "stage", "thread-s", "share");
        for s in Stage::ALL {
            let secs = self.seconds(s);
            if secs > 0.0 {
                let share = if total > 0.0 { secs / total } else { 0.0 };
                let _ = writeln!(
                    out,
                    "{:<20} {secs:>10.3} {:>6.1} %",
                    s.name(),
                    100.0 * share
                );
            }
        }
        let _ = write!(
            out,
            "{:<20} {total:>10.3}\nwall {:.3} s, {} tiles",
            "all stages",
            self.wall_seconds(),
            self.tiles()
        );
        let (all, kernels) = self.uploaded();
        if all > 0 {
            let _ = write!(
                out,
                "\nuploaded {all} bytes, the tiles' kernels {kernels} of them"
            );
        }
        out
    }
}

fn nanos(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

/// One thread's stage times, gathered without atomics and handed to [`Timings`] once
/// per tile ([`Timings::absorb`]). Off, it reads no clock.
#[derive(Clone, Debug, Default)]
pub struct Clock {
    on: bool,
    nanos: [u64; STAGES],
    tiles: u64,
}

impl Clock {
    #[must_use]
    pub fn new(on: bool) -> Self {
        Self {
            on,
            ..Self::default()
        }
    }

    pub fn set_on(&mut self, on: bool) {
        self.on = on;
    }

    #[must_use]
    pub fn start(&self) -> Option<Instant> {
        self.on.then(Instant::now)
    }

    pub fn stop(&mut self, stage: Stage, started: Option<Instant>) {
        if let Some(s) = started {
            self.nanos[stage.index()] += nanos(s.elapsed());
        }
    }

    pub fn tile_done(&mut self) {
        self.tiles += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clock_off_records_nothing_and_one_on_is_absorbed_once() {
        let t = Timings::new();
        let mut off = Clock::new(false);
        let s = off.start();
        assert!(s.is_none());
        off.stop(Stage::Solve, s);
        t.absorb(&mut off);
        assert_eq!(t.seconds(Stage::Solve), 0.0);

        let mut on = Clock::new(true);
        let s = on.start();
        std::hint::black_box((0..1000).sum::<u64>());
        on.stop(Stage::Solve, s);
        on.tile_done();
        t.absorb(&mut on);
        let once = t.seconds(Stage::Solve);
        assert!(once > 0.0);
        t.absorb(&mut on);
        assert_eq!(t.seconds(Stage::Solve), once, "absorbing empties the clock");
        assert_eq!(t.tiles(), 1);
        assert!(t.table().contains("solver passes"));
    }
}
