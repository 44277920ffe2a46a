//! What every subcommand shares: progress bars, JSON output, the chart option.

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use lensblur::chart::ChartSpec;
use lensblur::job::JobContext;
use std::path::Path;
use std::sync::{Arc, Mutex};

/// A job context that draws an indicatif progress bar on stderr (hidden when stderr is
/// not a terminal, so scripts and CI logs stay clean).
pub fn progress_job() -> JobContext {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} {elapsed_precise}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let bar = Arc::new(Mutex::new(bar));
    JobContext::with_sink(move |p| {
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
