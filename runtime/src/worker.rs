//! A running role as the supervisor holds it: a child process, or a thread of the
//! launcher's own process.

use std::process::Child;
use std::thread::JoinHandle;

use anyhow::Result;

/// A running role: a child process, or a thread of this one.
pub enum Worker {
    Process(Child),
    Thread(Option<JoinHandle<Result<()>>>),
}

impl Worker {
    /// `None` while it runs; then `Ok` for a clean exit or why it did not exit cleanly.
    pub fn finished(&mut self) -> Option<Result<(), String>> {
        match self {
            Worker::Process(child) => match child.try_wait() {
                Ok(None) => None,
                Ok(Some(status)) if status.success() => Some(Ok(())),
                Ok(Some(status)) => Some(Err(format!("exited with {status}"))),
                Err(e) => Some(Err(format!("cannot be waited for: {e}"))),
            },
            // Joined once, when it finished; the slot is done after that.
            Worker::Thread(handle) => handle.take_if(|h| h.is_finished()).map(|h| match h.join() {
                Ok(Ok(())) => Ok(()),
                Ok(Err(e)) => Err(format!("{e:#}")),
                Err(_) => Err("panicked".into()),
            }),
        }
    }

    pub fn kill(&mut self) {
        if let Worker::Process(child) = self {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    pub fn pid(&self) -> Option<u32> {
        match self {
            Worker::Process(child) => Some(child.id()),
            Worker::Thread(_) => None,
        }
    }
}
