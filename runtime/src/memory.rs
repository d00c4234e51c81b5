//! A process's memory over a run, as its MCAP log records it every [`MEMORY_EVERY`]: what
//! the kernel holds resident for it (whole, and its anonymous part: heap and stacks), and
//! the bytes the program itself holds allocated ("live"), where the binary's allocator
//! counts them ([`count_live_bytes_with`]). Resident memory that grows while live bytes stay
//! level is the allocator keeping what was freed; live bytes that grow are data the program
//! keeps.

use std::sync::OnceLock;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::{Duration, Instant};

use anyhow::Result;
use mcaplog::RunLog;
use serde::{Deserialize, Serialize};

use crate::stopwatch::status_mb;
use rundir::record::PROCESS_MEMORY;

/// How often a process logs its memory.
pub const MEMORY_EVERY: Duration = Duration::from_secs(10);

/// The binary's count of the bytes its allocator has handed out and not had back.
static LIVE_BYTES: OnceLock<fn() -> usize> = OnceLock::new();

/// Names where this process's live bytes are counted (the binary's global allocator); the
/// first call stands. Without one, records carry no live figure.
pub fn count_live_bytes_with(live_bytes: fn() -> usize) {
    let _ = LIVE_BYTES.set(live_bytes);
}

/// One sample of this process's memory, in MB.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MemoryRecord {
    /// Resident (`VmRSS`).
    pub rss_mb: f64,
    /// The resident part that is the process's own (`RssAnon`): heap, stacks.
    pub anon_mb: f64,
    /// Allocated by the program and not yet freed, where the allocator counts it.
    pub live_mb: Option<f64>,
}

impl MemoryRecord {
    pub fn of_this_process() -> Self {
        let field = |name| status_mb("self", name).unwrap_or(0.0);
        Self {
            rss_mb: field("VmRSS:"),
            anon_mb: field("RssAnon:"),
            live_mb: LIVE_BYTES
                .get()
                .map(|live_bytes| live_bytes() as f64 / (1024.0 * 1024.0)),
        }
    }
}

/// Logs this process's memory when [`MEMORY_EVERY`] has passed since it last did.
pub struct MemorySampler {
    next: Instant,
}

impl Default for MemorySampler {
    fn default() -> Self {
        Self {
            next: Instant::now(),
        }
    }
}

impl MemorySampler {
    pub fn log_if_due(&mut self, log: &RunLog) -> Result<()> {
        if Instant::now() >= self.next {
            log_memory(log)?;
            self.next = Instant::now() + MEMORY_EVERY;
        }
        Ok(())
    }
}

/// Logs this process's memory now.
fn log_memory(log: &RunLog) -> Result<()> {
    log.json(PROCESS_MEMORY, &MemoryRecord::of_this_process())?;
    Ok(())
}

/// Runs `work` while a thread beside it logs this process's memory every [`MEMORY_EVERY`],
/// from its start to its end (the last sample at the end).
pub fn sampling_memory<T>(log: &RunLog, work: impl FnOnce() -> T) -> T {
    std::thread::scope(|scope| {
        let (done, until_done) = mpsc::channel::<()>();
        // A log that fails is the role's to report (its own writes fail too).
        scope.spawn(move || {
            let _ = log_memory(log);
            while let Err(RecvTimeoutError::Timeout) = until_done.recv_timeout(MEMORY_EVERY) {
                let _ = log_memory(log);
            }
            let _ = log_memory(log);
        });
        let result = work();
        drop(done);
        result
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_process_logs_its_memory_from_start_to_end() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("memory.mcap");
        let log = RunLog::create(&path, "test").unwrap();
        let held = sampling_memory(&log, || {
            std::thread::sleep(Duration::from_millis(50));
            vec![1u8; 64 << 20]
        });
        log.finish().unwrap();
        let records: Vec<MemoryRecord> = mcaplog::json_messages(&path, PROCESS_MEMORY)
            .unwrap()
            .into_iter()
            .map(|value| serde_json::from_value(value).unwrap())
            .collect();
        // One at the start, one at the end: the 64 MB just allocated is resident at the end.
        assert_eq!(records.len(), 2, "{records:?}");
        assert!(records[0].rss_mb > 0.0 && records[0].anon_mb > 0.0);
        assert!(records[1].rss_mb >= records[0].rss_mb + 60.0, "{records:?}");
        // This test binary's allocator is not counted.
        assert!(records.iter().all(|r| r.live_mb.is_none()));
        assert_eq!(held.len(), 64 << 20);
    }
}
