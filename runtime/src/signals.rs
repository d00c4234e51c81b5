//! The launcher's signal handlers: Ctrl-C and SIGTERM stop the run, SIGUSR1 asks the
//! buffer for a snapshot.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result};

/// What the launcher's signal handlers raise.
pub struct Signals {
    /// Ctrl-C or SIGTERM: stop the run.
    interrupted: Arc<AtomicBool>,
    /// SIGUSR1 (`kill -USR1 <launcher>`): the buffer snapshots now.
    snapshot: Arc<AtomicBool>,
}

impl Signals {
    pub fn install() -> Result<Self> {
        use signal_hook::consts::{SIGINT, SIGTERM, SIGUSR1};
        let interrupted = Arc::new(AtomicBool::new(false));
        for signal in [SIGINT, SIGTERM] {
            signal_hook::flag::register(signal, interrupted.clone())
                .context("installing the Ctrl-C handler")?;
        }
        let snapshot = Arc::new(AtomicBool::new(false));
        signal_hook::flag::register(SIGUSR1, snapshot.clone())
            .context("installing the SIGUSR1 handler")?;
        Ok(Self {
            interrupted,
            snapshot,
        })
    }

    pub fn interrupted(&self) -> bool {
        self.interrupted.load(Ordering::SeqCst)
    }

    /// Whether a snapshot was asked for since the last call.
    pub fn snapshot_asked(&self) -> bool {
        self.snapshot.swap(false, Ordering::SeqCst)
    }
}
