//! What an actor process tells the supervisor of its environments: their progress at each
//! episode's end and once a second, also while it waits (for its first weights, or in a send
//! the buffer's rate limiter holds back). So an actor that is only waiting is heard, and one
//! that is hung (stopped, a physics step that never returns) falls silent and is restarted.
//! Its environments step together, one batch an action, so one stuck environment silences
//! its whole process: the process is the unit the supervisor judges and restarts.

use std::time::{Duration, Instant};

use wire::{Message, Outbox, Status, TransportError};

/// How often the reports go out while nothing else is said: well inside the smallest
/// heartbeat limit the tests use (3 s).
const EVERY: Duration = Duration::from_secs(1);

pub(super) struct Heartbeat {
    status: Outbox,
    /// Each environment's latest report.
    latest: Vec<Status>,
    /// When they all last went out.
    sent: Option<Instant>,
}

impl Heartbeat {
    /// `first`: each environment's report before it played.
    pub(super) fn new(status: Outbox, first: Vec<Status>) -> Self {
        Self {
            status,
            latest: first,
            sent: None,
        }
    }

    /// Takes each environment's report after an action; those in `ended` (their episode
    /// ended) go out at once, all of them once a second.
    pub(super) fn report(&mut self, latest: Vec<Status>, ended: &[usize]) -> anyhow::Result<()> {
        self.latest = latest;
        for &env in ended {
            self.status
                .send(&Message::Status(self.latest[env].clone()))?;
        }
        Ok(self.beat()?)
    }

    /// Sends every environment's latest report, if a second has passed since they last went.
    pub(super) fn beat(&mut self) -> Result<(), TransportError> {
        if self.sent.is_some_and(|at| at.elapsed() < EVERY) {
            return Ok(());
        }
        for report in &self.latest {
            self.status.send(&Message::Status(report.clone()))?;
        }
        self.sent = Some(Instant::now());
        Ok(())
    }
}
