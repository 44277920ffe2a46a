//! RAW decoding in a worker process. The RAW decoders are large, and a file made to
//! confuse one (or just damaged in the wrong place) can make it allocate without bound,
//! loop forever or abort: none of that can be caught inside a process, and in the
//! studio or a batch of 500 photos it would take everything down. So the command line
//! and the studio hand each RAW file to a worker: this same program, started with the
//! hidden `decode-worker` subcommand, under an address-space limit it sets on itself
//! and a time limit its parent keeps. Whatever happens to the worker becomes one
//! refusal naming the file; the parent goes on.
//!
//! Workers are kept between files (idle ones wait on their input), so a batch pays one
//! start-up per concurrent decode, not one per file; one that died is replaced. A worker
//! reads a file on disk itself (mapped, its address-space limit sized from the file's
//! length) and hands back a mosaic as its 16-bit samples in a memory file the parent
//! maps (`wire`): the parent makes the planes in one pass, as it would in process.
//! Library users decode in process unless they choose a worker ([`set_decoding`]): the
//! worker is a program, and only the caller knows where one is.

use super::wire::{self, Answer, Input, Job, ReceivedInput, Request};
use super::{LoadError, OnDisk};
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::{Arc, Mutex, PoisonError, RwLock};
use std::time::Duration;

/// The hidden subcommand that makes the program a worker.
pub const WORKER_SUBCOMMAND: &str = "decode-worker";

/// Where RAW files are decoded.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Decoding {
    /// In this process: what a library user gets unless it chooses otherwise, and what
    /// the worker itself does.
    #[default]
    InProcess,
    /// In worker processes of a program that runs [`serve`] for its
    /// [`WORKER_SUBCOMMAND`] (the `lensblur` executable does).
    Worker(WorkerLimits),
}

/// A worker program and the limits each decode runs under.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WorkerLimits {
    pub program: PathBuf,
    /// Address space for a decode: this, plus [`WorkerLimits::memory_per_file_byte`]
    /// times the file's length (the file itself, the decoder's image and our planes
    /// grow with it).
    pub memory_bytes: u64,
    pub memory_per_file_byte: u64,
    /// Time for a decode: this, plus a second per [`WorkerLimits::bytes_per_second`]
    /// of the file (rawler decodes tens of MB a second on one core).
    pub time: Duration,
    pub bytes_per_second: u64,
}

impl WorkerLimits {
    /// 4 GiB plus 8 bytes per byte of the file (the largest image lensblur accepts, a
    /// 300 MP file, decodes in under 3 GB), 60 s plus a second per 5 MB.
    #[must_use]
    pub fn new(program: PathBuf) -> Self {
        Self {
            program,
            memory_bytes: 4 << 30,
            memory_per_file_byte: 8,
            time: Duration::from_secs(60),
            bytes_per_second: 5 << 20,
        }
    }

    fn memory_for(&self, file_bytes: usize) -> u64 {
        self.memory_bytes
            .saturating_add(self.memory_per_file_byte.saturating_mul(file_bytes as u64))
    }

    fn time_for(&self, file_bytes: usize) -> Duration {
        self.time + Duration::from_secs(file_bytes as u64 / self.bytes_per_second.max(1))
    }
}

impl Decoding {
    /// Workers of the running program: for the `lensblur` executable itself (its
    /// command line and studio), which serves [`WORKER_SUBCOMMAND`]. In process where
    /// the platform has no address-space limit to set or the program cannot be found.
    #[must_use]
    pub fn this_program() -> Self {
        match std::env::current_exe() {
            Ok(program) if cfg!(unix) => Decoding::Worker(WorkerLimits::new(program)),
            _ => Decoding::InProcess,
        }
    }
}

static DECODING: RwLock<Decoding> = RwLock::new(Decoding::InProcess);

thread_local! {
    /// This thread's choice, inside [`with_decoding`].
    static SCOPED: std::cell::RefCell<Option<Decoding>> = const { std::cell::RefCell::new(None) };
}

/// Chooses where every RAW decode of this process runs from now on (but inside
/// [`with_decoding`]).
pub fn set_decoding(decoding: Decoding) {
    *DECODING.write().unwrap_or_else(PoisonError::into_inner) = decoding;
}

/// Runs `f` with this thread's RAW decodes where `decoding` says, whatever the
/// process's choice: a test or a fuzzing run can use a worker of its own, with limits of
/// its own, beside code that decodes in process.
pub fn with_decoding<T>(decoding: &Decoding, f: impl FnOnce() -> T) -> T {
    struct Restore(Option<Decoding>);
    impl Drop for Restore {
        fn drop(&mut self) {
            SCOPED.set(self.0.take());
        }
    }
    let _restore = Restore(SCOPED.replace(Some(decoding.clone())));
    f()
}

/// Where this thread's RAW decodes run now.
#[must_use]
pub fn decoding() -> Decoding {
    SCOPED.with_borrow(Clone::clone).unwrap_or_else(|| {
        DECODING
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    })
}

/// A job on a RAW file's bytes, where [`decoding`] says. A worker reads the file
/// itself where the bytes are the file on disk (`on_disk`): they need not go through
/// a pipe.
pub(super) fn run(
    job: Job,
    path: &Path,
    bytes: &[u8],
    on_disk: OnDisk,
) -> Result<Answer, LoadError> {
    match decoding() {
        Decoding::InProcess => super::run_in_process(job, path, bytes),
        Decoding::Worker(limits) => {
            let absolute = std::path::absolute(path).ok();
            let input = match &absolute {
                Some(at) if on_disk.0 && wire::path_goes_over(at) => Input::File {
                    len: bytes.len() as u64,
                },
                _ => Input::Bytes(bytes),
            };
            let request = Request {
                job,
                memory_bytes: limits.memory_for(bytes.len()),
                path: absolute.as_deref().unwrap_or(path),
                input,
            };
            in_worker(&limits, &request, path, limits.time_for(bytes.len()))
        }
    }
}

/// Workers waiting for their next file, each with the program and limits it was
/// started for (a worker's heap keeps what earlier files took, so one started under
/// other limits is not reused).
static IDLE: Mutex<Vec<Worker>> = Mutex::new(Vec::new());

/// A request through a worker, within `time`: an idle one of the same program if there
/// is one, else a new one; kept for the next file if it answered. `path` is the file's
/// name in messages.
fn in_worker(
    limits: &WorkerLimits,
    request: &Request<'_>,
    path: &Path,
    time: Duration,
) -> Result<Answer, LoadError> {
    let idle = {
        let mut idle = IDLE.lock().unwrap_or_else(PoisonError::into_inner);
        let at = idle.iter().position(|w| w.limits == *limits);
        at.map(|at| idle.swap_remove(at))
    };
    let reused = idle.is_some();
    let mut worker = match idle {
        Some(w) => w,
        None => start(limits, path)?,
    };
    let mut answer = worker.exchange(request, path, time);
    // A worker kept from an earlier file may have been ended meanwhile (by a signal
    // from outside): the file is judged by a fresh one.
    if reused && matches!(answer, Err(Death::Ended { .. })) {
        worker = start(limits, path)?;
        answer = worker.exchange(request, path, time);
    }
    match answer {
        Ok(answer) => {
            let mut idle = IDLE.lock().unwrap_or_else(PoisonError::into_inner);
            // At most one idle worker per core: more would only wait.
            if idle.len() < std::thread::available_parallelism().map_or(1, usize::from) {
                idle.push(worker);
            }
            answer
        }
        Err(death) => Err(LoadError::DecoderStopped {
            path: path.to_path_buf(),
            reason: death.words(request.memory_bytes, time),
        }),
    }
}

fn start(limits: &WorkerLimits, path: &Path) -> Result<Worker, LoadError> {
    Worker::start(limits).map_err(|e| LoadError::Unreadable {
        path: path.to_path_buf(),
        reason: format!(
            "cannot start the RAW decoder ({} {WORKER_SUBCOMMAND}): {e}",
            limits.program.display()
        ),
    })
}

/// What became of a worker that gave no answer.
#[derive(Debug)]
enum Death {
    /// It ran past its time and was stopped.
    Timeout,
    /// It ended: its exit status, and whether its last words were a failed allocation.
    Ended {
        status: Option<std::process::ExitStatus>,
        out_of_memory: bool,
        stack_overflow: bool,
    },
}

impl Death {
    const CURE: &str = "the file is damaged or made in a way the decoder cannot follow; \
                        copy it from the card again, or convert it to DNG with Adobe DNG \
                        Converter or `dnglab convert` and open the DNG";

    /// One line: what happened to the decoder on the file, and what to do.
    fn words(&self, memory: u64, time: Duration) -> String {
        let what = match self {
            Death::Timeout => format!(
                "the RAW decoder took longer than {} s on it and was stopped",
                time.as_secs()
            ),
            Death::Ended {
                out_of_memory: true,
                ..
            } => format!(
                "the RAW decoder ran out of memory on it (it may use {:.1} GB)",
                memory as f64 / 1e9
            ),
            Death::Ended {
                stack_overflow: true,
                ..
            } => "the RAW decoder crashed on it (its stack overflowed)".to_string(),
            Death::Ended { status, .. } => match status.and_then(signal) {
                // The file is mapped as it is read: one cut short meanwhile is a bus error.
                #[cfg(unix)]
                Some(libc::SIGBUS) => "the file was cut short while the RAW decoder read it: \
                                       open it again once it is whole"
                    .to_string(),
                Some(s) => format!("the RAW decoder crashed on it (signal {s})"),
                None => format!(
                    "the RAW decoder stopped on it without an answer ({})",
                    status.map_or_else(|| "no exit status".into(), |s| s.to_string())
                ),
            },
        };
        format!("{what}: {}", Self::CURE)
    }
}

#[cfg(unix)]
fn signal(status: std::process::ExitStatus) -> Option<i32> {
    std::os::unix::process::ExitStatusExt::signal(&status)
}

#[cfg(not(unix))]
fn signal(_: std::process::ExitStatus) -> Option<i32> {
    None
}

/// How much of a worker's standard error is kept: its last words.
const STDERR_TAIL: usize = 4096;

/// A running worker and its pipes.
struct Worker {
    limits: WorkerLimits,
    child: Child,
    input: Option<BufWriter<ChildStdin>>,
    output: BufReader<ChildStdout>,
    /// The memory file it writes mosaics' samples into, where the system has them.
    shared: Option<File>,
    /// The end of what it wrote to standard error (where a failed allocation says so),
    /// gathered by `stderr_reader` until it exits.
    stderr: Arc<Mutex<Vec<u8>>>,
    stderr_reader: Option<std::thread::JoinHandle<()>>,
}

impl Worker {
    fn start(limits: &WorkerLimits) -> std::io::Result<Self> {
        let mut command = Command::new(&limits.program);
        command
            .arg(WORKER_SUBCOMMAND)
            // glibc reserves address space per thread arena (64 MB each): on a machine
            // of many cores that alone would eat the limit.
            .env("MALLOC_ARENA_MAX", "2")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let shared = shared_memory(&mut command);
        let mut child = command.spawn()?;
        let missing = || std::io::Error::other("no pipe to the worker");
        let input = child.stdin.take().ok_or_else(missing)?;
        let output = child.stdout.take().ok_or_else(missing)?;
        widen_pipe(&input);
        widen_pipe(&output);
        let mut err = child.stderr.take().ok_or_else(missing)?;
        let stderr = Arc::new(Mutex::new(Vec::new()));
        let tail = Arc::clone(&stderr);
        let stderr_reader = std::thread::spawn(move || {
            let mut buf = [0u8; 1024];
            while let Ok(n @ 1..) = err.read(&mut buf) {
                let mut t = tail.lock().unwrap_or_else(PoisonError::into_inner);
                t.extend_from_slice(&buf[..n]);
                let over = t.len().saturating_sub(STDERR_TAIL);
                t.drain(..over);
            }
        });
        Ok(Self {
            limits: limits.clone(),
            child,
            input: Some(BufWriter::with_capacity(1 << 16, input)),
            output: BufReader::with_capacity(1 << 16, output),
            shared,
            stderr,
            stderr_reader: Some(stderr_reader),
        })
    }

    /// Sends the request and reads the answer within `time` (a refusal naming `path`);
    /// a worker that does not answer is stopped (if it still runs) and what became of
    /// it said.
    fn exchange(
        &mut self,
        request: &Request<'_>,
        path: &Path,
        time: Duration,
    ) -> Result<Result<Answer, LoadError>, Death> {
        let Some(input) = self.input.as_mut() else {
            return Err(self.ended());
        };
        let (output, shared) = (&mut self.output, self.shared.as_ref());
        let answered = std::thread::scope(|s| {
            let (tx, rx) = std::sync::mpsc::channel();
            s.spawn(move || {
                let answer = wire::write_request(&mut *input, request)
                    .and_then(|()| wire::read_answer(&mut *output, path, shared));
                let _ = tx.send(answer);
            });
            match rx.recv_timeout(time) {
                Ok(answer) => Some(answer),
                Err(_) => {
                    // Killing it closes its pipes, which ends the exchange's thread.
                    let _ = self.child.kill();
                    None
                }
            }
        });
        match answered {
            Some(Ok(answer)) => Ok(answer),
            Some(Err(_)) => Err(self.ended()),
            None => {
                let _ = self.child.wait();
                Err(Death::Timeout)
            }
        }
    }

    /// The worker broke off the exchange: it ended (or, having written nonsense, is
    /// stopped); its exit status and last words.
    fn ended(&mut self) -> Death {
        self.input = None;
        let status = match self.child.try_wait() {
            Ok(Some(s)) => Some(s),
            _ => {
                // It closed its output but has not exited, or wrote what is not an
                // answer: it is of no more use.
                let _ = self.child.kill();
                self.child.wait().ok()
            }
        };
        if let Some(reader) = self.stderr_reader.take() {
            let _ = reader.join();
        }
        let tail = self.stderr.lock().unwrap_or_else(PoisonError::into_inner);
        let said = String::from_utf8_lossy(&tail);
        Death::Ended {
            status,
            out_of_memory: said.contains("memory allocation of"),
            stack_overflow: said.contains("has overflowed its stack"),
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        // Its input closed, an idle worker exits; reaped so no zombie is left.
        self.input = None;
        if self.child.try_wait().ok().flatten().is_none() {
            let _ = self.child.wait();
        }
    }
}

/// A pipe's buffer as large as the system lets a process make it (1 MiB by default,
/// from 64 kB): a 24 MP file's planes are 96 MB, and each buffer's worth is a switch
/// between the two processes.
#[cfg(target_os = "linux")]
fn widen_pipe(pipe: &impl std::os::fd::AsRawFd) {
    // SAFETY: fcntl on a descriptor this process owns; a refusal leaves the pipe as it was.
    let _ = unsafe { libc::fcntl(pipe.as_raw_fd(), libc::F_SETPIPE_SZ, 1 << 20) };
}

#[cfg(not(target_os = "linux"))]
fn widen_pipe<T>(_: &T) {}

/// The worker's side: answers requests on standard input until it ends, each under
/// the request's address-space limit. Standard output carries the answers alone; what
/// anything else prints goes to standard error.
///
/// # Errors
/// The input is not a request, or the output cannot be written (the parent is gone).
pub fn serve() -> std::io::Result<()> {
    let answers = answer_channel()?;
    let shared = shared_memory_given();
    let mut out = BufWriter::with_capacity(1 << 16, answers);
    let mut input = std::io::BufReader::with_capacity(1 << 16, std::io::stdin().lock());
    while let Some(r) = wire::read_request(&mut input)? {
        limit_address_space(r.memory_bytes)?;
        let answer = match r.input {
            ReceivedInput::Bytes(bytes) => super::run_in_process(r.job, &r.path, &bytes),
            ReceivedInput::File { len } => match map_file(&r.path, len) {
                Ok(map) => super::run_in_process(r.job, &r.path, map.as_deref().unwrap_or(&[])),
                Err(e) => Err(e),
            },
        };
        wire::write_answer(&mut out, &answer, shared.as_ref())?;
        out.flush()?;
    }
    Ok(())
}

/// The file a request names, mapped (not copied: the decoders read it as a slice);
/// `None` for an empty file. Refused if its length is not what the parent read.
fn map_file(path: &Path, len: u64) -> Result<Option<memmap2::Mmap>, LoadError> {
    let unreadable = |reason: String| LoadError::Unreadable {
        path: path.to_path_buf(),
        reason,
    };
    let file = File::open(path).map_err(|e| unreadable(e.to_string()))?;
    let now = file
        .metadata()
        .map_err(|e| unreadable(e.to_string()))?
        .len();
    if now != len {
        return Err(unreadable(format!(
            "the file changed while it was read ({len} bytes, then {now}); open it again \
             once it is written"
        )));
    }
    if len == 0 {
        return Ok(None);
    }
    // SAFETY: a file a user gave us, read-only. Were it cut short while mapped, reading
    // past its new end would end this worker with SIGBUS, which its parent reports as
    // a crash on the file: the one process a damaged read may take down is this one.
    unsafe { memmap2::Mmap::map(&file) }
        .map(Some)
        .map_err(|e| unreadable(e.to_string()))
}

/// The environment variable that tells a worker the descriptor of its shared memory
/// file.
const SHARED_FD_VAR: &str = "LENSBLUR_DECODE_SHARED_FD";
/// The descriptor a worker's shared memory file has in the worker.
#[cfg(target_os = "linux")]
const SHARED_FD: i32 = 3;

/// A memory file for the worker `command` starts to hand mosaics back in, given to it
/// as descriptor [`SHARED_FD`]; `None` where the system has none (the pipe then
/// carries them).
#[cfg(target_os = "linux")]
fn shared_memory(command: &mut Command) -> Option<File> {
    use std::os::fd::{AsRawFd, FromRawFd};
    use std::os::unix::process::CommandExt;
    // SAFETY: memfd_create returns a new descriptor (owned by the File alone) or -1.
    let fd = unsafe { libc::memfd_create(c"lensblur-mosaic".as_ptr(), libc::MFD_CLOEXEC) };
    if fd < 0 {
        return None;
    }
    // SAFETY: as above.
    let file = unsafe { File::from_raw_fd(fd) };
    let raw = file.as_raw_fd();
    // SAFETY: between fork and exec only dup2 and fcntl run, both async-signal-safe;
    // the descriptor stays open in the parent until the spawn returns.
    unsafe {
        command.pre_exec(move || {
            let done = if raw == SHARED_FD {
                libc::fcntl(raw, libc::F_SETFD, 0)
            } else {
                libc::dup2(raw, SHARED_FD)
            };
            if done < 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    command.env(SHARED_FD_VAR, SHARED_FD.to_string());
    Some(file)
}

#[cfg(not(target_os = "linux"))]
fn shared_memory(_: &mut Command) -> Option<File> {
    None
}

/// The worker's shared memory file, where its parent gave it one: the descriptor
/// [`SHARED_FD_VAR`] names, if it is a memory file (one started by hand has none).
#[cfg(target_os = "linux")]
fn shared_memory_given() -> Option<File> {
    use std::os::fd::FromRawFd;
    let fd: i32 = std::env::var(SHARED_FD_VAR).ok()?.parse().ok()?;
    // SAFETY: F_GET_SEALS only reads; it succeeds on memory files alone, so the
    // descriptor is the parent's memory file, which this process then owns.
    (fd == SHARED_FD && unsafe { libc::fcntl(fd, libc::F_GET_SEALS) } >= 0)
        .then(|| unsafe { File::from_raw_fd(fd) })
}

#[cfg(not(target_os = "linux"))]
fn shared_memory_given() -> Option<File> {
    None
}

/// Standard output, moved to a descriptor of its own, and standard error put in its
/// place: a decoder's stray print can then never be read as part of an answer.
#[cfg(unix)]
fn answer_channel() -> std::io::Result<std::fs::File> {
    use std::os::fd::FromRawFd;
    std::io::stdout().flush()?;
    // SAFETY: plain descriptor calls; the descriptor `dup` returns is new and owned
    // by the File alone.
    unsafe {
        let fd = libc::dup(1);
        if fd < 0 || libc::dup2(2, 1) < 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok(std::fs::File::from_raw_fd(fd))
    }
}

#[cfg(not(unix))]
fn answer_channel() -> std::io::Result<std::io::Stdout> {
    Ok(std::io::stdout())
}

/// Sets the worker's address-space limit (soft: it can be set again, higher or lower,
/// for the next request).
#[cfg(unix)]
fn limit_address_space(bytes: u64) -> std::io::Result<()> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit on a valid struct of this process's own.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_AS, &mut limit) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        limit.rlim_cur = bytes.min(limit.rlim_max);
        if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
}

#[cfg(not(unix))]
fn limit_address_space(_: u64) -> std::io::Result<()> {
    Ok(())
}
