//! The topics of a run and how each is delivered.

/// What a topic does when a subscriber falls behind.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Delivery {
    /// Nothing is dropped: a publisher waits for room (back-pressure).
    Lossless,
    /// The oldest unread message is dropped for the newest (weights, progress reports:
    /// only the latest matters).
    Latest,
}

/// Who publishes a topic and who reads it, as a run's processes on one machine share it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fan {
    /// One publisher, one reader: requests (learner -> buffer), batches (buffer -> learner).
    OneToOne,
    /// Every process may publish, one reads: steps (every actor -> the buffer), status
    /// (every role -> the launcher).
    ManyToOne,
    /// One publishes, every process may read: weights (the learner -> every actor), control
    /// (the launcher -> every role).
    OneToMany,
}

/// A named stream of messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Topic {
    /// Steps and episode ends, every actor -> the buffer.
    Steps,
    /// Sample requests and priority updates, learner -> buffer.
    Requests,
    /// Batches, buffer -> learner.
    Batches,
    /// Weights, learner -> every actor.
    Weights,
    /// Orders, launcher -> every role.
    Control,
    /// Progress reports, every role -> launcher.
    Status,
}

impl Topic {
    pub const ALL: [Topic; 6] = [
        Topic::Steps,
        Topic::Requests,
        Topic::Batches,
        Topic::Weights,
        Topic::Control,
        Topic::Status,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Topic::Steps => "steps",
            Topic::Requests => "requests",
            Topic::Batches => "batches",
            Topic::Weights => "weights",
            Topic::Control => "control",
            Topic::Status => "status",
        }
    }

    pub fn delivery(self) -> Delivery {
        match self {
            Topic::Steps | Topic::Requests | Topic::Batches | Topic::Control => Delivery::Lossless,
            Topic::Weights | Topic::Status => Delivery::Latest,
        }
    }

    pub fn fan(self) -> Fan {
        match self {
            Topic::Requests | Topic::Batches => Fan::OneToOne,
            Topic::Steps | Topic::Status => Fan::ManyToOne,
            Topic::Weights | Topic::Control => Fan::OneToMany,
        }
    }

    /// Unread messages a subscriber holds before back-pressure (lossless) or overwriting
    /// (latest) sets in. Steps keep few: 0.5 MB steps that wait long fall out of the cache
    /// (measured by `bench transport`: 4 instead of 32 takes one publisher from 1.3x to
    /// 1.5-2x a Unix socket's bandwidth on two cores).
    pub fn buffer(self) -> usize {
        match self {
            Topic::Steps => 4,
            Topic::Requests | Topic::Control => 16,
            Topic::Batches => 4,
            Topic::Weights => 1,
            Topic::Status => 256,
        }
    }

    /// [`Topic::buffer`] for a publisher that sends for `envs` environments at once (an actor
    /// process of several): the steps topic holds as many of each environment's, so that
    /// one action of all of them (a step and an episode end each) waits in the buffer
    /// rather than in a publisher blocked behind the others.
    pub fn buffer_for(self, envs: usize) -> usize {
        match self {
            Topic::Steps => self.buffer() * envs.max(1),
            _ => self.buffer(),
        }
    }

    /// Messages kept for subscribers that join later: the newest weights, and the newest
    /// order (an actor restarted after a stop still stops).
    pub fn history(self) -> usize {
        match self {
            Topic::Weights | Topic::Control => 1,
            _ => 0,
        }
    }
}
