//! Crossbeam channels between the threads of one process: the same topics and deliveries as
//! shared memory, for tests and the `--threads` mode. Each subscriber owns a bounded channel;
//! a publisher sends a shared copy of the bytes to every subscriber alive when it sends.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use crossbeam_channel::{Receiver, SendTimeoutError, Sender, TrySendError, bounded};

use crate::error::TransportError;
use crate::topic::{Delivery, Topic};
use crate::transport::{Publisher, Subscriber, Transport, WAITING_EVERY, Waiting};

type Bytes = Arc<[u8]>;

/// One run's topics inside a process; clones share them. Two transports made with
/// [`ChannelTransport::new`] never see each other's messages.
#[derive(Clone, Default)]
pub struct ChannelTransport {
    hub: Arc<Mutex<HashMap<Topic, TopicState>>>,
}

#[derive(Default)]
struct TopicState {
    subscribers: Vec<Inlet>,
    history: VecDeque<Bytes>,
}

/// The sending side of one subscriber's channel.
#[derive(Clone)]
struct Inlet {
    sender: Sender<Bytes>,
    /// Lets a publisher drop the oldest message of a full `Latest` channel.
    oldest: Receiver<Bytes>,
    alive: Arc<AtomicBool>,
}

impl Inlet {
    /// Whether the subscriber is still there to take `bytes`.
    fn deliver(
        &self,
        bytes: &Bytes,
        delivery: Delivery,
        waiting: Waiting<'_>,
    ) -> Result<bool, TransportError> {
        match delivery {
            Delivery::Lossless => loop {
                match self.sender.send_timeout(bytes.clone(), WAITING_EVERY) {
                    Ok(()) => return Ok(true),
                    Err(SendTimeoutError::Timeout(_)) => waiting()?,
                    Err(SendTimeoutError::Disconnected(_)) => return Ok(false),
                }
            },
            Delivery::Latest => Ok(self.overwrite(bytes)),
        }
    }

    /// Delivers `bytes` in place of the oldest unread message if the channel is full;
    /// whether the subscriber is still there.
    fn overwrite(&self, bytes: &Bytes) -> bool {
        loop {
            match self.sender.try_send(bytes.clone()) {
                Ok(()) => return true,
                Err(TrySendError::Full(_)) => {
                    let _ = self.oldest.try_recv();
                }
                Err(TrySendError::Disconnected(_)) => return false,
            }
        }
    }
}

impl ChannelTransport {
    pub fn new() -> Self {
        Self::default()
    }

    fn hub(&self) -> MutexGuard<'_, HashMap<Topic, TopicState>> {
        // A thread that panicked while holding the lock left the map itself intact.
        self.hub.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl Transport for ChannelTransport {
    fn publisher(&self, topic: Topic) -> Result<Box<dyn Publisher>, TransportError> {
        Ok(Box::new(ChannelPublisher {
            transport: self.clone(),
            topic,
        }))
    }

    fn subscriber(&self, topic: Topic) -> Result<Box<dyn Subscriber>, TransportError> {
        let (sender, receiver) = bounded(topic.buffer());
        let alive = Arc::new(AtomicBool::new(true));
        let inlet = Inlet {
            sender,
            oldest: receiver.clone(),
            alive: alive.clone(),
        };
        let mut hub = self.hub();
        let state = hub.entry(topic).or_default();
        for bytes in &state.history {
            inlet.overwrite(bytes);
        }
        state.subscribers.push(inlet);
        Ok(Box::new(ChannelSubscriber { receiver, alive }))
    }
}

struct ChannelPublisher {
    transport: ChannelTransport,
    topic: Topic,
}

impl Publisher for ChannelPublisher {
    fn send_waiting(&mut self, bytes: &[u8], waiting: Waiting<'_>) -> Result<(), TransportError> {
        let bytes: Bytes = bytes.into();
        let inlets = {
            let mut hub = self.transport.hub();
            let state = hub.entry(self.topic).or_default();
            state
                .subscribers
                .retain(|s| s.alive.load(Ordering::Acquire));
            if self.topic.history() > 0 {
                if state.history.len() == self.topic.history() {
                    state.history.pop_front();
                }
                state.history.push_back(bytes.clone());
            }
            state.subscribers.clone()
        };
        // Outside the lock: a lossless send may wait for its subscriber to read.
        for inlet in &inlets {
            if !inlet.deliver(&bytes, self.topic.delivery(), waiting)? {
                inlet.alive.store(false, Ordering::Release);
            }
        }
        Ok(())
    }
}

struct ChannelSubscriber {
    receiver: Receiver<Bytes>,
    alive: Arc<AtomicBool>,
}

impl Subscriber for ChannelSubscriber {
    fn receive(&mut self, sink: &mut dyn FnMut(&[u8])) -> Result<bool, TransportError> {
        match self.receiver.try_recv() {
            Ok(bytes) => {
                sink(&bytes);
                Ok(true)
            }
            Err(_) => Ok(false),
        }
    }
}

impl Drop for ChannelSubscriber {
    fn drop(&mut self) {
        self.alive.store(false, Ordering::Release);
        // Wake a lossless publisher waiting on this full channel.
        while self.receiver.try_recv().is_ok() {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::{Inbox, Outbox};
    use messages::{Control, Message, Role};

    fn stop(role: Role) -> Message {
        Message::Control(Control::Stop(role))
    }

    #[test]
    fn lossless_topics_deliver_everything_in_order_under_back_pressure() {
        let transport = ChannelTransport::new();
        let mut inbox = Inbox::open(&transport, Topic::Steps).unwrap();
        let n = Topic::Steps.buffer() * 4;
        let sender = {
            let transport = transport.clone();
            std::thread::spawn(move || {
                let mut outbox = Outbox::open(&transport, Topic::Steps).unwrap();
                for i in 0..n {
                    let role = [Role::Actor, Role::Buffer, Role::Learner][i % 3];
                    outbox.send(&stop(role)).unwrap();
                }
            })
        };
        let mut received = Vec::new();
        while received.len() < n {
            match inbox.try_recv().unwrap() {
                Some(m) => received.push(m),
                None => std::thread::yield_now(),
            }
        }
        sender.join().unwrap();
        let expected: Vec<Message> = (0..n)
            .map(|i| stop([Role::Actor, Role::Buffer, Role::Learner][i % 3]))
            .collect();
        assert_eq!(received, expected);
    }

    #[test]
    fn latest_topics_keep_the_newest_and_give_it_to_late_subscribers() {
        let transport = ChannelTransport::new();
        let mut early = Inbox::open(&transport, Topic::Weights).unwrap();
        let mut outbox = Outbox::open(&transport, Topic::Weights).unwrap();
        for role in [Role::Actor, Role::Buffer, Role::Learner] {
            outbox.send(&stop(role)).unwrap();
        }
        assert_eq!(early.drain().unwrap(), vec![stop(Role::Learner)]);
        let mut late = Inbox::open(&transport, Topic::Weights).unwrap();
        assert_eq!(late.drain().unwrap(), vec![stop(Role::Learner)]);
    }

    #[test]
    fn transports_and_topics_stay_apart() {
        let (a, b) = (ChannelTransport::new(), ChannelTransport::new());
        let mut a_control = Inbox::open(&a, Topic::Control).unwrap();
        let mut b_control = Inbox::open(&b, Topic::Control).unwrap();
        let mut a_status = Inbox::open(&a, Topic::Status).unwrap();
        Outbox::open(&a, Topic::Control)
            .unwrap()
            .send(&stop(Role::Buffer))
            .unwrap();
        assert_eq!(a_control.drain().unwrap(), vec![stop(Role::Buffer)]);
        assert!(b_control.drain().unwrap().is_empty());
        assert!(a_status.drain().unwrap().is_empty());
    }

    #[test]
    fn a_dropped_subscriber_does_not_block_a_lossless_publisher() {
        let transport = ChannelTransport::new();
        let inbox = Inbox::open(&transport, Topic::Batches).unwrap();
        let mut outbox = Outbox::open(&transport, Topic::Batches).unwrap();
        for _ in 0..Topic::Batches.buffer() {
            outbox.send(&stop(Role::Learner)).unwrap();
        }
        drop(inbox);
        outbox.send(&stop(Role::Learner)).unwrap();
    }

    #[test]
    fn another_protocol_version_is_refused_on_receipt() {
        let transport = ChannelTransport::new();
        let mut inbox = Inbox::open(&transport, Topic::Steps).unwrap();
        let mut bytes = Vec::new();
        messages::codec::encode_with_version(&stop(Role::Actor), 99, &mut bytes);
        Outbox::open(&transport, Topic::Steps)
            .unwrap()
            .send_raw(&bytes)
            .unwrap();
        let err = inbox.try_recv().unwrap_err();
        assert!(err.to_string().contains("protocol version 99"), "{err}");
    }
}
