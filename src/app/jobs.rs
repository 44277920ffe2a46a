//! Long work off the UI thread: one named thread per job, a [`JobContext`] whose
//! progress sink wakes the UI, results through one bounded channel, and a handle whose
//! drop cancels the work.
//!
//! A job that works on the open session says so ([`JobScope`]): its results carry the
//! session they belong to, so the app drops what arrives after it switched sessions,
//! and each shot it works on can be cancelled alone when the shot is removed.

use crate::job::{JobContext, Progress};
use crate::session::ShotId;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// What a job works on: the session (the app's count of sessions opened, so a result
/// for an earlier one is recognised) and the shots, each cancellable alone.
#[derive(Clone, Debug, Default)]
pub struct JobScope {
    pub session: Option<u64>,
    pub shots: Vec<ShotId>,
}

impl JobScope {
    #[must_use]
    pub fn session(session: u64) -> Self {
        Self {
            session: Some(session),
            shots: Vec::new(),
        }
    }

    #[must_use]
    pub fn shots(session: u64, shots: Vec<ShotId>) -> Self {
        Self {
            session: Some(session),
            shots,
        }
    }
}

/// What a job does. The studio tells its jobs apart by this (is one running, what
/// follows its end); [`JobKind::name`] is only what the window and the log call it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum JobKind {
    /// Making the demo session (on a pool of its own).
    DemoSession,
    /// Reading a reopened session's cached results.
    ReadResults,
    /// Loading shots for display.
    LoadShot,
    Detect,
    Kernels,
    /// Gathering the measured Gaussians into the session's dataset.
    GatherMeasurements,
    Calibrate,
    /// Whatever the session lacks measured, then calibration.
    CalibrateAll,
    LoadProfile,
    OpenPhoto,
    /// The Deblur view's crops or whole photo, replaced by a newer one as a control
    /// is dragged.
    DeblurPreview,
    /// The photo deblurred whole and written.
    ExportPhoto,
    ExportPhotos,
    /// The square inspector's crops.
    InspectSquare,
    /// The lens's geometry measured from the detections.
    Geometry,
    LensfunExport,
}

impl JobKind {
    /// What the window, the log and the job's thread call it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::DemoSession => "demo session",
            Self::ReadResults => "read results",
            Self::LoadShot => "load shot",
            Self::Detect => "detect",
            Self::Kernels => "kernels",
            Self::GatherMeasurements => "gather measurements",
            Self::Calibrate => "calibrate",
            Self::CalibrateAll => "calibrate all",
            Self::LoadProfile => "load profile",
            Self::OpenPhoto => "open photo",
            Self::DeblurPreview => "deblur preview",
            Self::ExportPhoto => "export",
            Self::ExportPhotos => "export photos",
            Self::InspectSquare => "inspect square",
            Self::Geometry => "geometry",
            Self::LensfunExport => "lensfun export",
        }
    }
}

impl std::fmt::Display for JobKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How a job ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JobEnd {
    Done,
    /// Stopped by a cancel (its own, its session's or a newer job's).
    Cancelled,
    /// The one-line reason it failed (a panic included).
    Failed(String),
}

/// The cancel flag of every shot a job works on.
type ShotFlags = Arc<BTreeMap<ShotId, Arc<AtomicBool>>>;

/// What a finished (or partly finished) job hands back to the UI thread.
pub enum JobEvent<T> {
    /// A result that is ready now; more may follow from the same job. `session` is the
    /// job's [`JobScope::session`].
    Output {
        job: u64,
        session: Option<u64>,
        output: T,
    },
    /// The job stopped.
    Finished {
        job: u64,
        kind: JobKind,
        end: JobEnd,
    },
}

/// A running job as the UI sees it.
pub struct JobHandle {
    pub id: u64,
    pub kind: JobKind,
    pub started: Instant,
    pub session: Option<u64>,
    ctx: JobContext,
    progress: Arc<Mutex<Option<Progress>>>,
    shots: ShotFlags,
}

impl JobHandle {
    #[must_use]
    pub fn progress(&self) -> Option<Progress> {
        self.progress.lock().ok().and_then(|p| p.clone())
    }

    pub fn cancel(&self) {
        self.ctx.cancel();
    }

    #[must_use]
    pub fn is_cancelled(&self) -> bool {
        self.ctx.is_cancelled()
    }

    /// Cancels the job's work on one shot: the whole job when that is all it does.
    /// Returns whether the job worked on that shot.
    pub fn cancel_shot(&self, shot: ShotId) -> bool {
        let Some(flag) = self.shots.get(&shot) else {
            return false;
        };
        if self.shots.len() == 1 {
            self.cancel();
        } else {
            flag.store(true, Ordering::Relaxed);
        }
        true
    }
}

impl Drop for JobHandle {
    fn drop(&mut self) {
        // Dropping the handle (closing the app, replacing the session) must stop the
        // work rather than leave a thread computing into a channel nobody reads.
        self.ctx.cancel();
    }
}

/// Sends a job's partial results to the UI and wakes it.
pub struct Emitter<T> {
    job: u64,
    session: Option<u64>,
    tx: SyncSender<JobEvent<T>>,
    wake: Arc<dyn Fn() + Send + Sync>,
    shots: ShotFlags,
}

impl<T> Emitter<T> {
    pub fn emit(&self, output: T) {
        // A closed channel means the app is gone; the work is then cancelled anyway.
        let _ = self.tx.send(JobEvent::Output {
            job: self.job,
            session: self.session,
            output,
        });
        (self.wake)();
    }

    /// The context for the job's work on one shot of its scope: cancelled with the job,
    /// or alone when the shot is removed; `None` when it already was.
    #[must_use]
    pub fn shot_context(&self, ctx: &JobContext, shot: ShotId) -> Option<JobContext> {
        let flag = self.shots.get(&shot)?;
        let part = ctx.part(Arc::clone(flag));
        (!part.is_cancelled()).then_some(part)
    }
}

/// The set of jobs and the channel their results arrive on.
pub struct Jobs<T> {
    next_id: u64,
    pub running: Vec<JobHandle>,
    tx: SyncSender<JobEvent<T>>,
    rx: Receiver<JobEvent<T>>,
    /// Called when a job has ended.
    wake: Arc<dyn Fn() + Send + Sync>,
    /// Called when a job hands over a result on its way.
    output_wake: Arc<dyn Fn() + Send + Sync>,
    /// Called when only a job's progress changed: the window may take its time.
    progress_wake: Arc<dyn Fn() + Send + Sync>,
    /// Where jobs compute; `None` if it could not be built (rayon's global pool then).
    pool: Option<Arc<rayon::ThreadPool>>,
    /// How many workers a pool of jobs has.
    threads: usize,
}

/// A pool for jobs: `threads` workers at a lower priority than the window.
fn job_pool(threads: usize, name: &'static str) -> Option<Arc<rayon::ThreadPool>> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(move |i| format!("{name}-{i}"))
        .start_handler(|_| lower_priority())
        .build()
        .ok()
        .map(Arc::new)
}

impl<T: Send + 'static> Jobs<T> {
    /// `wake` is called from worker threads whenever there is something new to show.
    /// Jobs compute on `threads` threads; 0 means one per core. They run at a lower
    /// priority than the window, so the UI thread (and, under a software renderer, the
    /// rasteriser) takes a core whenever it draws; and the window draws a few times a
    /// second while only progress changes, so between frames the jobs have every core.
    pub fn new(threads: usize, wake: impl Fn() + Send + Sync + 'static) -> Self {
        // Bounded: a fast producer waits for the UI rather than queueing without limit.
        let (tx, rx) = sync_channel(64);
        let threads = if threads == 0 {
            std::thread::available_parallelism().map_or(2, std::num::NonZeroUsize::get)
        } else {
            threads
        };
        let wake: Arc<dyn Fn() + Send + Sync> = Arc::new(wake);
        Self {
            next_id: 1,
            running: Vec::new(),
            tx,
            rx,
            progress_wake: Arc::clone(&wake),
            output_wake: Arc::clone(&wake),
            wake,
            pool: job_pool(threads, "job-worker"),
            threads,
        }
    }

    /// What to call when only a job's progress changed (by default the same as for a
    /// result): the studio repaints once a second for it, not every frame, so
    /// the jobs keep the cores.
    #[must_use]
    pub fn with_progress_wake(mut self, wake: impl Fn() + Send + Sync + 'static) -> Self {
        self.progress_wake = Arc::new(wake);
        self
    }

    /// What to call when a job hands over a result before its end (by default the same
    /// as for its end): the studio lets a stream of them share a frame.
    #[must_use]
    pub fn with_output_wake(mut self, wake: impl Fn() + Send + Sync + 'static) -> Self {
        self.output_wake = Arc::new(wake);
        self
    }

    /// Starts `work` on a pool of its own, so that it holds back no other job: a job
    /// runs whole on one of its pool's workers, so on a two-core machine (one worker) the
    /// demo's minute of simulation would keep the shots it has made from being loaded
    /// and shown until the last was made. Its workers too run at a lower priority.
    ///
    /// # Errors
    /// The thread could not be spawned.
    pub fn spawn_apart(
        &mut self,
        kind: JobKind,
        work: impl FnOnce(&JobContext, &Emitter<T>) -> Result<(), String> + Send + 'static,
    ) -> Result<u64, String> {
        let pool = job_pool(self.threads, "apart-worker");
        self.spawn_on(kind, JobScope::default(), pool, work)
    }

    /// Starts `work` on its own named thread.
    ///
    /// # Errors
    /// The thread could not be spawned.
    pub fn spawn(
        &mut self,
        kind: JobKind,
        work: impl FnOnce(&JobContext, &Emitter<T>) -> Result<(), String> + Send + 'static,
    ) -> Result<u64, String> {
        self.spawn_scoped(kind, JobScope::default(), work)
    }

    /// Starts `work` on its own named thread, working on `scope`.
    ///
    /// # Errors
    /// The thread could not be spawned.
    pub fn spawn_scoped(
        &mut self,
        kind: JobKind,
        scope: JobScope,
        work: impl FnOnce(&JobContext, &Emitter<T>) -> Result<(), String> + Send + 'static,
    ) -> Result<u64, String> {
        let pool = self.pool.clone();
        self.spawn_on(kind, scope, pool, work)
    }

    fn spawn_on(
        &mut self,
        kind: JobKind,
        scope: JobScope,
        pool: Option<Arc<rayon::ThreadPool>>,
        work: impl FnOnce(&JobContext, &Emitter<T>) -> Result<(), String> + Send + 'static,
    ) -> Result<u64, String> {
        let shots: ShotFlags = Arc::new(
            scope
                .shots
                .iter()
                .map(|&s| (s, Arc::new(AtomicBool::new(false))))
                .collect(),
        );
        let id = self.next_id;
        self.next_id += 1;
        let progress = Arc::new(Mutex::new(None));
        let p2 = Arc::clone(&progress);
        let wake = Arc::clone(&self.progress_wake);
        let ctx = JobContext::with_sink(move |p| {
            if let Ok(mut slot) = p2.lock() {
                *slot = Some(p.clone());
            }
            wake();
        });
        let emitter = Emitter {
            job: id,
            session: scope.session,
            tx: self.tx.clone(),
            wake: Arc::clone(&self.output_wake),
            shots: Arc::clone(&shots),
        };
        let finished_wake = Arc::clone(&self.wake);
        let worker_ctx = ctx.clone();
        let name = kind.name();
        std::thread::Builder::new()
            .name(format!("job-{id}-{name}"))
            .spawn(move || {
                lower_priority();
                // A job that panics still ends: otherwise the studio would wait on it
                // (busy, its stage refused as "already running") until it is closed.
                let run = std::panic::AssertUnwindSafe(|| match pool.as_deref() {
                    Some(pool) => pool.install(|| work(&worker_ctx, &emitter)),
                    None => work(&worker_ctx, &emitter),
                });
                let result = std::panic::catch_unwind(run).unwrap_or_else(|panic| {
                    Err(format!(
                        "{name}: internal error: {}",
                        panic_message(panic.as_ref())
                    ))
                });
                let end = match result {
                    Ok(()) => JobEnd::Done,
                    Err(_) if worker_ctx.is_cancelled() => JobEnd::Cancelled,
                    Err(e) => JobEnd::Failed(e),
                };
                let _ = emitter.tx.send(JobEvent::Finished { job: id, kind, end });
                finished_wake();
            })
            .map_err(|e| format!("cannot start job '{name}': {e}"))?;
        self.running.push(JobHandle {
            id,
            kind,
            started: Instant::now(),
            session: scope.session,
            ctx,
            progress,
            shots,
        });
        Ok(id)
    }

    /// Everything that arrived since the last call, in order; finished jobs leave
    /// `running`.
    pub fn drain(&mut self) -> Vec<JobEvent<T>> {
        let events: Vec<_> = self.rx.try_iter().collect();
        for e in &events {
            if let JobEvent::Finished { job, .. } = e {
                self.running.retain(|h| h.id != *job);
            }
        }
        events
    }

    #[must_use]
    pub fn is_running(&self, kind: JobKind) -> bool {
        self.running.iter().any(|h| h.kind == kind)
    }

    pub fn cancel(&mut self, id: u64) {
        if let Some(h) = self.running.iter().find(|h| h.id == id) {
            h.cancel();
        }
    }

    /// Cancels every job working on a session: it is being closed.
    pub fn cancel_session_jobs(&self) {
        for h in self.running.iter().filter(|h| h.session.is_some()) {
            h.cancel();
        }
    }

    /// Cancels every job's work on a shot that is being removed.
    pub fn cancel_shot(&self, shot: ShotId) {
        for h in &self.running {
            h.cancel_shot(shot);
        }
    }
}

/// What a panic said, when it said it as text.
fn panic_message(panic: &(dyn std::any::Any + Send)) -> &str {
    panic
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| panic.downcast_ref::<String>().map(String::as_str))
        .unwrap_or("a panic without a message")
}

/// Lowers the calling thread's scheduling priority (nice 10): jobs then take the CPU
/// the window leaves, rather than the window waiting for a core behind them. On Linux a
/// thread's nice value is its own. Failure only costs responsiveness, so it is ignored.
fn lower_priority() {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: setpriority only reads its arguments; `who` = 0 is the calling thread.
        let _ = unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, 10) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;
    use std::time::Duration;

    /// A job that panics ends like one that failed, naming itself: the studio would
    /// otherwise count it as running until it is closed.
    #[test]
    fn a_panicking_job_finishes_with_an_error() {
        let (woken, wakes) = mpsc::channel();
        let mut jobs: Jobs<()> = Jobs::new(1, move || {
            let _ = woken.send(());
        });
        let id = jobs
            .spawn(JobKind::Kernels, |_ctx, _out| panic!("index out of bounds"))
            .expect("spawned");
        let result = loop {
            // A guard against a hang, not a timing: the job ends at once.
            wakes
                .recv_timeout(Duration::from_secs(60))
                .expect("the job ends");
            let finished = jobs.drain().into_iter().find_map(|e| match e {
                JobEvent::Finished { job, end, .. } if job == id => Some(end),
                _ => None,
            });
            if let Some(r) = finished {
                break r;
            }
        };
        assert_eq!(
            result,
            JobEnd::Failed("kernels: internal error: index out of bounds".to_owned())
        );
        assert!(jobs.running.is_empty());
    }

    /// A result on a job's way calls the output wake (the studio may let a stream of
    /// them share a frame), its end the job-end wake (which the studio never delays).
    #[test]
    fn results_and_ends_wake_through_their_own_callbacks() {
        let (woken, wakes) = mpsc::channel();
        let ended = woken.clone();
        let mut jobs: Jobs<u32> = Jobs::new(1, move || {
            let _ = ended.send("end");
        })
        .with_output_wake(move || {
            let _ = woken.send("output");
        });
        jobs.spawn(JobKind::Kernels, |_ctx, out| {
            out.emit(1);
            out.emit(2);
            Ok(())
        })
        .expect("spawned");
        let got: Vec<&str> = (0..3)
            .map(|_| {
                // A guard against a hang, not a timing: the job ends at once.
                wakes.recv_timeout(Duration::from_secs(60)).expect("a wake")
            })
            .collect();
        assert_eq!(got, ["output", "output", "end"]);
    }
}
