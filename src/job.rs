//! The small context a long computation receives: a cancel flag it checks between units
//! of work (squares, folds, tiles), and a sink for progress. The core never knows who
//! listens: the command line draws a progress bar, the studio wakes its UI.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Where a job stands: `done` of `total` units of the named stage.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Progress {
    pub stage: String,
    pub done: usize,
    pub total: usize,
}

type Sink = Arc<dyn Fn(&Progress) + Send + Sync>;

/// Cancel flag plus progress sink, cheap to clone into worker threads.
#[derive(Clone)]
pub struct JobContext {
    cancel: Arc<AtomicBool>,
    /// The enclosing job's flag, for a part of it that can also be cancelled alone
    /// ([`JobContext::part`]).
    outer: Option<Arc<AtomicBool>>,
    sink: Option<Sink>,
    /// Where a deblur notes its stages' times, when the caller wants them.
    timings: Option<Arc<crate::timings::Timings>>,
}

/// Returned by work that stopped because it was cancelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("cancelled")]
pub struct Cancelled;

impl Default for JobContext {
    fn default() -> Self {
        Self::silent()
    }
}

impl std::fmt::Debug for JobContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JobContext")
            .field("cancelled", &self.is_cancelled())
            .finish()
    }
}

impl JobContext {
    /// No progress reported, never cancelled (tests, scripts).
    #[must_use]
    pub fn silent() -> Self {
        Self {
            cancel: Arc::new(AtomicBool::new(false)),
            outer: None,
            sink: None,
            timings: None,
        }
    }

    /// Reports every progress update to `sink`.
    #[must_use]
    pub fn with_sink(sink: impl Fn(&Progress) + Send + Sync + 'static) -> Self {
        Self {
            cancel: Arc::new(AtomicBool::new(false)),
            outer: None,
            sink: Some(Arc::new(sink)),
            timings: None,
        }
    }

    /// The same job, noting a deblur's stage times in `timings`.
    #[must_use]
    pub fn with_timings(&self, timings: Arc<crate::timings::Timings>) -> JobContext {
        JobContext {
            timings: Some(timings),
            ..self.clone()
        }
    }

    /// Where to note stage times, if anywhere.
    #[must_use]
    pub fn timings(&self) -> Option<&crate::timings::Timings> {
        self.timings.as_deref()
    }

    pub fn cancel(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }

    #[must_use]
    pub fn is_cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
            || self
                .outer
                .as_ref()
                .is_some_and(|o| o.load(Ordering::Relaxed))
    }

    /// A part of this job (one shot of a stage run over many) that `flag` cancels on
    /// its own, while cancelling the whole job still cancels the part. Progress goes
    /// to the same sink.
    #[must_use]
    pub fn part(&self, flag: Arc<AtomicBool>) -> JobContext {
        JobContext {
            cancel: flag,
            outer: Some(Arc::clone(&self.cancel)),
            sink: self.sink.clone(),
            timings: self.timings.clone(),
        }
    }

    /// The same job's cancellation without its progress: work run several at a time
    /// under one progress (photos of a batch) would otherwise fight over the bar.
    #[must_use]
    pub fn without_progress(&self) -> JobContext {
        JobContext {
            sink: None,
            ..self.clone()
        }
    }

    /// # Errors
    /// [`Cancelled`] once the job has been cancelled.
    pub fn check(&self) -> Result<(), Cancelled> {
        if self.is_cancelled() {
            Err(Cancelled)
        } else {
            Ok(())
        }
    }

    /// The same job (one cancel flag) reporting each stage as `prefix` + its name: work
    /// that runs a stage over several shots says which shot it is on.
    #[must_use]
    pub fn prefixed(&self, prefix: &str) -> JobContext {
        let Some(parent) = self.sink.clone() else {
            return self.clone();
        };
        let prefix = prefix.to_owned();
        JobContext {
            cancel: Arc::clone(&self.cancel),
            outer: self.outer.clone(),
            timings: self.timings.clone(),
            sink: Some(Arc::new(move |p: &Progress| {
                parent(&Progress {
                    stage: format!("{prefix}{}", p.stage),
                    done: p.done,
                    total: p.total,
                });
            })),
        }
    }

    pub fn report(&self, stage: &str, done: usize, total: usize) {
        if let Some(sink) = &self.sink {
            sink(&Progress {
                stage: stage.to_owned(),
                done,
                total,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[test]
    fn cancel_and_progress() {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let s2 = Arc::clone(&seen);
        let job =
            JobContext::with_sink(move |p| s2.lock().unwrap().push((p.stage.clone(), p.done)));
        job.report("x", 1, 3);
        job.report("x", 2, 3);
        assert_eq!(seen.lock().unwrap().len(), 2);
        assert!(job.check().is_ok());
        let shot = job.prefixed("shot 2/3: ");
        shot.report("detect", 5, 9);
        let clone = job.clone();
        clone.cancel();
        assert_eq!(job.check(), Err(Cancelled));
        assert_eq!(
            shot.check(),
            Err(Cancelled),
            "a prefixed context shares the flag"
        );
        assert_eq!(
            *seen.lock().unwrap(),
            vec![
                ("x".into(), 1),
                ("x".into(), 2),
                ("shot 2/3: detect".into(), 5)
            ]
        );
    }

    #[test]
    fn a_part_is_cancelled_alone_or_with_its_job() {
        let job = JobContext::silent();
        let flag = Arc::new(AtomicBool::new(false));
        let part = job.part(Arc::clone(&flag));
        let other = job.part(Arc::new(AtomicBool::new(false)));
        flag.store(true, Ordering::Relaxed);
        assert!(part.is_cancelled() && part.prefixed("x").is_cancelled());
        assert!(!other.is_cancelled() && !job.is_cancelled());
        job.cancel();
        assert!(other.is_cancelled());
    }
}
