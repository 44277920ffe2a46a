//! The project's writer thread: `session.json` written off the caller's thread, the
//! newest copy first.

use crate::session::{Session, SessionError};
use std::sync::{Arc, mpsc};

/// Writes `session.json` on a thread of its own, the newest copy first.
pub(super) struct Saver {
    tx: Option<mpsc::Sender<SaveRequest>>,
    thread: Option<std::thread::JoinHandle<()>>,
    failed: Arc<std::sync::Mutex<Option<String>>>,
}

enum SaveRequest {
    Save(Box<Session>),
    Flush(mpsc::Sender<()>),
}

impl Saver {
    pub(super) fn start() -> Self {
        let (tx, rx) = mpsc::channel::<SaveRequest>();
        let failed = Arc::new(std::sync::Mutex::new(None));
        let failures = Arc::clone(&failed);
        let thread = std::thread::Builder::new()
            .name("lensblur session writer".into())
            .spawn(move || {
                let mut pending: Option<Box<Session>> = None;
                while let Ok(first) = rx.recv() {
                    // Only the newest copy matters: take everything waiting first.
                    let mut requests = vec![first];
                    requests.extend(rx.try_iter());
                    let mut acks = Vec::new();
                    for r in requests {
                        match r {
                            SaveRequest::Save(s) => pending = Some(s),
                            SaveRequest::Flush(ack) => acks.push(ack),
                        }
                    }
                    if let Some(s) = pending.take()
                        && let Err(e) = s.save()
                        && let Ok(mut f) = failures.lock()
                    {
                        *f = Some(e.to_string());
                    }
                    for ack in acks {
                        let _ = ack.send(());
                    }
                }
            })
            .ok();
        Self {
            tx: thread.as_ref().map(|_| tx),
            thread,
            failed,
        }
    }

    pub(super) fn save(&self, session: &Session) -> Result<(), SessionError> {
        match &self.tx {
            Some(tx)
                if tx
                    .send(SaveRequest::Save(Box::new(session.clone())))
                    .is_ok() =>
            {
                Ok(())
            }
            // No writer thread could be started: write here.
            _ => session.save(),
        }
    }

    pub(super) fn flush(&self) {
        if let Some(tx) = &self.tx {
            let (ack, done) = mpsc::channel();
            if tx.send(SaveRequest::Flush(ack)).is_ok() {
                let _ = done.recv();
            }
        }
    }

    pub(super) fn take_failure(&self) -> Option<String> {
        self.failed.lock().ok().and_then(|mut f| f.take())
    }
}

impl Drop for Saver {
    fn drop(&mut self) {
        // Closing the channel ends the thread once it has written what it was given.
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
