//! How large a run's shared memory is: the publishers, subscribers and nodes each topic
//! admits, sized from the run's processes on this machine, and the memory that takes.
//!
//! iceoryx2 fixes a service's limits when the first process creates it and refuses a port
//! past them (`ExceedsMaxSupportedSubscribers`), and it reserves each publisher's memory for
//! the worst case its limits allow: max subscribers times the messages each may hold
//! (buffer and borrowed), plus history and the publisher's loans, each message the run's
//! largest step or, on other topics, rounded up to a power of two. A reserved page takes
//! memory only once written (the segments are sparse files in /dev/shm), so a run's
//! footprint is two figures: what its files reserve, and what its messages can write at
//! most.

use iceoryx2::prelude::AllocationStrategy;

use crate::topic::{Fan, Topic};

use super::{INITIAL_SLICE, kept};

/// Ports and nodes a topic admits per process of the run: its own, and those of a dead
/// predecessor not yet removed (a restarted role removes dead nodes as it starts).
const PER_PROCESS: usize = 2;

/// Publishers of a topic that has one, or subscribers of a topic that one reads: it, its
/// restarted successor while the dead one is not yet removed, and room to spare.
const SINGLE: usize = 4;

/// Messages a publisher may hold on loan at once (iceoryx2's default).
const LOANS: usize = 2;

/// The processes of one run on one machine that open its topics (a launcher or a joined
/// host, and the roles it starts), from which every topic's limits follow, and the largest
/// step they send. Every process of the run must open its topics with the same limits, so
/// the launcher gives its own to the roles it starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShmLimits {
    processes: usize,
    /// Environments an actor process steps, whose messages its one publisher of steps
    /// sends together.
    envs_per_process: usize,
    /// The largest message on the steps topic, in bytes as encoded (`largest_step`): what a
    /// publisher of steps reserves each message up front (see `ShmTransport::publisher`).
    largest_step: usize,
}

/// The largest message of the topics other than steps whose messages can outgrow the first
/// slice a publisher reserves, in bytes as encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LargestMessages {
    pub batch: usize,
    pub weights: usize,
}

/// A run's shared memory in bytes: what its publishers' files reserve, and what their
/// messages can write at most when every reader holds as many as it may.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShmFootprint {
    pub reserved: u64,
    pub written: u64,
}

impl ShmLimits {
    /// Limits for a run of `processes` processes on this machine (at least one), whose
    /// steps are at most `largest_step` bytes as encoded.
    pub const fn for_run(processes: usize, largest_step: usize) -> Self {
        Self {
            processes: if processes == 0 { 1 } else { processes },
            envs_per_process: 1,
            largest_step,
        }
    }

    /// These limits for actor processes of `envs` environments each (at least one).
    pub const fn with_envs_per_process(self, envs: usize) -> Self {
        Self {
            envs_per_process: if envs == 0 { 1 } else { envs },
            ..self
        }
    }

    pub fn processes(self) -> usize {
        self.processes
    }

    pub fn largest_step(self) -> usize {
        self.largest_step
    }

    /// Unread messages a subscriber of `topic` holds per publisher.
    pub(super) fn buffer(self, topic: Topic) -> usize {
        topic.buffer_for(self.envs_per_process)
    }

    pub(super) fn nodes(self) -> usize {
        PER_PROCESS * self.processes
    }

    pub(super) fn publishers(self, topic: Topic) -> usize {
        match topic.fan() {
            Fan::ManyToOne => PER_PROCESS * self.processes,
            Fan::OneToOne | Fan::OneToMany => SINGLE,
        }
    }

    pub(super) fn subscribers(self, topic: Topic) -> usize {
        match topic.fan() {
            Fan::OneToMany => PER_PROCESS * self.processes,
            Fan::OneToOne | Fan::ManyToOne => SINGLE,
        }
    }

    /// The shared memory of the run's live publishers, every one of a topic sending its
    /// largest message.
    pub fn footprint(self, largest: &LargestMessages) -> ShmFootprint {
        let mut footprint = ShmFootprint::default();
        for topic in Topic::ALL {
            let (publishers, readers) = match topic.fan() {
                Fan::OneToOne => (1, 1),
                Fan::ManyToOne => (self.processes, 1),
                Fan::OneToMany => (1, self.processes),
            };
            let slot = self.slot(topic, largest) as u64;
            // A reader holds its unread buffer, the message it reads and those it keeps.
            let held = self.buffer(topic) + 1 + kept(topic);
            let slots = |subscribers: usize| (subscribers * held + topic.history() + LOANS) as u64;
            footprint.reserved += publishers as u64 * slots(self.subscribers(topic)) * slot;
            footprint.written += publishers as u64 * slots(readers) * slot;
        }
        footprint
    }

    /// How a publisher of `topic` holds its messages, and the slice it reserves first:
    /// steps in memory reserved for the run's largest up front, which stays readable once
    /// the subscriber connected (see the transport's docs); other messages in memory that
    /// grows with them in powers of two.
    pub(super) fn memory(self, topic: Topic) -> (AllocationStrategy, usize) {
        match topic {
            Topic::Steps => (AllocationStrategy::Static, self.largest_step),
            _ => (AllocationStrategy::PowerOfTwo, INITIAL_SLICE),
        }
    }

    /// The memory a publisher of `topic` reserves for each message sending its largest.
    fn slot(self, topic: Topic, largest: &LargestMessages) -> usize {
        let (allocation, first) = self.memory(topic);
        let largest = match topic {
            Topic::Batches => largest.batch,
            Topic::Weights => largest.weights,
            Topic::Steps | Topic::Requests | Topic::Control | Topic::Status => first,
        };
        match allocation {
            AllocationStrategy::Static => first,
            _ => largest.max(first).next_power_of_two(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_grow_with_the_run_where_every_process_takes_part() {
        let small = ShmLimits::for_run(5, 100_000);
        let large = ShmLimits::for_run(131, 100_000);
        assert_eq!(large.subscribers(Topic::Control), 262);
        assert_eq!(large.publishers(Topic::Steps), 262);
        assert_eq!(large.nodes(), 262);
        for topic in [Topic::Requests, Topic::Batches] {
            assert_eq!(small.publishers(topic), large.publishers(topic));
            assert_eq!(small.subscribers(topic), large.subscribers(topic));
        }
        assert_eq!(ShmLimits::for_run(0, 100_000).processes(), 1);
    }

    #[test]
    fn a_process_of_several_environments_gets_room_for_each_ones_steps() {
        let limits = ShmLimits::for_run(5, 100_000).with_envs_per_process(4);
        assert_eq!(limits.buffer(Topic::Steps), 4 * Topic::Steps.buffer());
        assert_eq!(limits.buffer(Topic::Batches), Topic::Batches.buffer());
        let largest = LargestMessages {
            batch: 3_000,
            weights: 200_000,
        };
        let one = ShmLimits::for_run(5, 100_000).footprint(&largest);
        let four = limits.footprint(&largest);
        assert!(four.written > one.written && four.reserved > one.reserved);
    }

    #[test]
    fn a_footprint_counts_steps_exactly_and_other_messages_in_power_of_two_slots() {
        let largest = LargestMessages {
            batch: 3_000,
            weights: 200_000,
        };
        let one = ShmLimits::for_run(1, 100_000).footprint(&largest);
        let two = ShmLimits::for_run(2, 100_000).footprint(&largest);
        // One more process: one more publisher of steps (one reader holding 4 + 1 + 3, and
        // 2 loans, of 100,000 bytes), of status (1 x (256 + 1) + 2 of 4 KiB); one more
        // reader of weights (1 + 1 of 256 KiB) and of control (16 + 1 of 4 KiB).
        let written = 10 * 100_000 + 259 * 4096 + 2 * 262_144 + 17 * 4096;
        assert_eq!(two.written - one.written, written);
        assert!(two.reserved > two.written && one.reserved > one.written);
    }
}
