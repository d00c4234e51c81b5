//! The sending end of a shared-memory topic: one send, and the waits of a lossless one while
//! its reader's buffer is full.

use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::{BackpressureAction, BackpressureInfo};
use iceoryx2::prelude::PortFactory as _;
use iceoryx2::prelude::{AllocationStrategy, ipc};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;

use crate::error::TransportError;
use crate::topic::{Delivery, Topic};
use crate::transport::{Publisher, WAITING_EVERY, Waiting};

/// How long to wait before the next try of a send that found no room: 50 us, doubling to
/// 2 ms.
fn backoff(attempt: u64) -> Duration {
    (Duration::from_micros(50) * 2u32.pow(attempt.min(6) as u32)).min(Duration::from_millis(2))
}

/// While a subscriber's buffer stays full, a publisher sleeps between tries. iceoryx2's own
/// wait yields to the scheduler 10,000 times before it first sleeps: an actor held back by
/// the rate limiter spun on a core that the learner it waited for needed (a sixth of an
/// actor's time in `perf`, on two cores). After `patience` it gives up on the message (the
/// sender tries again, after its `waiting`: see [`Publisher::send_waiting`]).
pub(super) fn wait_for_room(
    info: &BackpressureInfo,
    patience: Option<Duration>,
) -> BackpressureAction {
    if patience.is_some_and(|p| info.elapsed_time >= p) {
        return BackpressureAction::DiscardData;
    }
    std::thread::sleep(backoff(info.retries));
    BackpressureAction::Retry
}

pub(super) struct ShmPublisher {
    pub(super) topic: Topic,
    pub(super) publisher: IoxPublisher<ipc::Service, [u8], ()>,
    pub(super) service: PortFactory<ipc::Service, [u8], ()>,
}

impl ShmPublisher {
    /// Sends once: to how many subscribers the message went.
    fn send_once(&self, bytes: &[u8]) -> Result<usize, TransportError> {
        let sample = self.publisher.loan_slice_uninit(bytes.len()).map_err(|e| {
            let what = match self.publisher.allocation_strategy() {
                AllocationStrategy::Static => format!(
                    "loaning shared memory for a message of {} bytes, where the run's \
                     largest is {}",
                    bytes.len(),
                    self.publisher.initial_max_slice_len()
                ),
                _ => "loaning shared memory".into(),
            };
            TransportError::iceoryx2(self.topic, &what, e)
        })?;
        sample
            .write_from_slice(bytes)
            .send()
            .map_err(|e| TransportError::iceoryx2(self.topic, "sending", e))
    }
}

impl Publisher for ShmPublisher {
    fn send_waiting(&mut self, bytes: &[u8], waiting: Waiting<'_>) -> Result<(), TransportError> {
        if self.topic.delivery() == Delivery::Latest {
            return self.send_once(bytes).map(|_| ());
        }
        // iceoryx2 waits for room only in the buffers of subscribers that have connected to
        // this publisher (they do so when they next look for messages); it drops the message
        // for a subscriber that has not and whose buffer is full, and for one whose buffer
        // stayed full past the handler's patience. When nobody took the message for either
        // reason, wait and send it again: nobody has it twice.
        let mut since_waiting = Instant::now();
        for attempt in 0.. {
            let subscribers = self.service.dynamic_config().number_of_subscribers();
            if self.send_once(bytes)? > 0 || subscribers == 0 {
                break;
            }
            if since_waiting.elapsed() >= WAITING_EVERY {
                waiting()?;
                since_waiting = Instant::now();
            }
            std::thread::sleep(backoff(attempt));
        }
        Ok(())
    }

    fn refresh(&mut self) -> Result<(), TransportError> {
        self.publisher
            .update_connections()
            .map_err(|e| TransportError::iceoryx2(self.topic, "connecting to new subscribers", e))
    }
}
