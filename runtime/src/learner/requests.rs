//! The learner's sample requests in flight: two, so the buffer samples the next batch while
//! this one trains.

use std::collections::VecDeque;

use anyhow::{Result, bail};
use wire::{BatchMessage, Message, Outbox, SampleRequest};

use rundir::config::RunConfig;

const IN_FLIGHT: usize = 2;
/// The counter bits of a sample request's id (below the learner's incarnation).
const COUNTER: u64 = (1 << 48) - 1;

/// The sample requests sent and not yet answered, oldest first. Ids carry the learner's
/// incarnation in their top bits, so a restarted learner never takes the answers to its
/// predecessor's requests for its own.
pub(super) struct Requests {
    next: u64,
    in_flight: VecDeque<u64>,
}

impl Requests {
    pub(super) fn new(incarnation: u32) -> Self {
        Self {
            next: u64::from(incarnation) << 48,
            in_flight: VecDeque::new(),
        }
    }

    /// Asks for batches until [`IN_FLIGHT`] are on their way, taking the stage's trained
    /// nets' primitives in turn.
    pub(super) fn keep_in_flight(
        &mut self,
        requests: &mut Outbox,
        config: &RunConfig,
    ) -> Result<()> {
        let nets = config.trained_nets();
        while self.in_flight.len() < IN_FLIGHT {
            let request = SampleRequest {
                id: self.next,
                primitive: nets[(self.next & COUNTER) as usize % nets.len()].primitive(),
                size: config.learner.batch_size,
            };
            requests.send(&Message::SampleRequest(request))?;
            self.in_flight.push_back(request.id);
            self.next += 1;
        }
        Ok(())
    }

    /// Whether `batch` answers a request in flight (else a predecessor's, or one forgotten
    /// when the buffer restarted), which must be the oldest.
    pub(super) fn answered(&mut self, batch: &BatchMessage) -> Result<bool> {
        if !self.in_flight.contains(&batch.request) {
            return Ok(false);
        }
        if self.in_flight.pop_front() != Some(batch.request) {
            bail!("the buffer answered request {} out of order", batch.request);
        }
        Ok(true)
    }

    /// Gives up on the requests in flight (the buffer that had them died); how many.
    pub(super) fn forget(&mut self) -> usize {
        let lost = self.in_flight.len();
        self.in_flight.clear();
        lost
    }
}
