//! What every subcommand shares: progress bars, JSON output, the chart option.

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use lensblur::chart::ChartSpec;
use lensblur::job::JobContext;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// A job context that draws an indicatif progress bar on stderr (hidden when stderr is
/// not a terminal, so scripts and CI logs stay clean).
pub fn progress_job() -> JobContext {
    progress_job_timed(None)
}

/// [`progress_job`], also noting in `clock` when each stage begins.
pub fn progress_job_timed(clock: Option<StageClock>) -> JobContext {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} {elapsed_precise}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let bar = Arc::new(Mutex::new(bar));
    JobContext::with_sink(move |p| {
        if let Some(clock) = &clock {
            clock.saw(&p.stage);
        }
        if let Ok(b) = bar.lock() {
            b.set_message(p.stage.clone());
            b.set_length(p.total as u64);
            b.set_position(p.done as u64);
            if p.done >= p.total && p.total > 0 {
                b.finish_and_clear();
            }
        }
    })
}

/// When each stage of a job began, in the order reported: a stage lasts until the next
/// one begins, so a command can say where its time went.
#[derive(Clone, Default)]
pub struct StageClock(Arc<Mutex<Vec<(String, Instant)>>>);

impl StageClock {
    fn saw(&self, stage: &str) {
        if let Ok(mut seen) = self.0.lock()
            && seen.last().is_none_or(|(s, _)| s != stage)
        {
            seen.push((stage.to_string(), Instant::now()));
        }
    }

    /// Seconds spent in each stage until `end`, a stage seen more than once summed, in
    /// the order first seen.
    pub fn durations(&self, end: Instant) -> Vec<(String, f64)> {
        let Ok(seen) = self.0.lock() else {
            return Vec::new();
        };
        let mut out: Vec<(String, f64)> = Vec::new();
        for (i, (stage, start)) in seen.iter().enumerate() {
            let until = seen.get(i + 1).map_or(end, |next| next.1);
            let secs = until.saturating_duration_since(*start).as_secs_f64();
            match out.iter_mut().find(|(s, _)| s == stage) {
                Some((_, total)) => *total += secs,
                None => out.push((stage.clone(), secs)),
            }
        }
        out
    }
}

/// The chart: the default 24 × 16 one, or the spec file given with `--chart`.
pub fn load_chart(path: Option<&Path>) -> Result<ChartSpec> {
    match path {
        None => Ok(ChartSpec::default()),
        Some(p) => Ok(ChartSpec::load(p)?),
    }
}

/// Writes `value` as pretty JSON, atomically and durably (see `lensblur::io`).
pub fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    Ok(lensblur::io::write_json(path, value)?)
}

/// Atomic, durable write of bytes.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    Ok(lensblur::io::write_atomic(path, bytes)?)
}

/// Refuses an output whose folder does not exist, before any work is done: a run of
/// minutes should not end on "cannot write".
pub fn check_out_folder(path: &Path) -> Result<()> {
    let folder = path.parent().filter(|p| !p.as_os_str().is_empty());
    match folder {
        Some(f) if !f.is_dir() => anyhow::bail!(
            "{}: the folder {} does not exist (create it first, or write elsewhere)",
            path.display(),
            f.display()
        ),
        _ => Ok(()),
    }
}

/// `--focal` and `--aperture`, where given, as positive numbers.
pub fn check_setting_args(focal: Option<f64>, aperture: Option<f64>) -> Result<()> {
    for (name, v) in [("--focal", focal), ("--aperture", aperture)] {
        if let Some(v) = v
            && !(v.is_finite() && v > 0.0)
        {
            anyhow::bail!("{name} must be a positive number (got {v})");
        }
    }
    Ok(())
}
