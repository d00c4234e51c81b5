//! What one action leaves behind, in the form every role shares: the actor makes a
//! [`Transition`], the buffer stores it (and its goal-relabelled copies) under a [`Key`],
//! the learner receives it as a [`BatchItem`] and sends the key back with a new priority.
//! Observations are stored and sent to the learner compressed ([`PackedObservation`]).
//! Plain data: the messages carry these types as they are.

pub mod batch;
pub mod observation;
pub mod transition;

pub use batch::{BatchItem, Key};
pub use observation::{CorruptObservation, PackedObservation, StoredTransition};
pub use transition::{Successor, Transition};
