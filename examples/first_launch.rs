//! What a newcomer waits for on first launch: the studio's demo session made as the
//! studio makes it (on every core but one, shot by shot), timing the first shot on disk
//! (the studio shows it at once) and the whole demo with its photo.
//!
//! `cargo run --release --example first_launch`

use lensblur::job::JobContext;
use lensblur::simulate::demo::{DemoSpec, make_demo_streaming};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let spec = DemoSpec::studio();
    // The studio's job threads: every core but one, the UI keeps the last.
    let cores = std::thread::available_parallelism().map_or(2, std::num::NonZeroUsize::get);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(cores.saturating_sub(1).max(1))
        .build()?;
    let t0 = Instant::now();
    let session = pool.install(|| {
        make_demo_streaming(dir.path(), &spec, &JobContext::silent(), &mut |s| {
            println!(
                "shot {} of {} on disk after {:.1} s",
                s.shots.len(),
                spec.settings.len(),
                t0.elapsed().as_secs_f64()
            );
        })
    })?;
    println!(
        "whole demo ({} shots of {} x {} and the photo) after {:.1} s on {} job threads",
        session.shots.len(),
        spec.width,
        spec.height,
        t0.elapsed().as_secs_f64(),
        pool.current_num_threads()
    );
    Ok(())
}
