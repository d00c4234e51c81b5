//! What one action leaves behind, in the form every role shares: the actor makes a
//! [`Transition`], the buffer stores it (and its goal-relabelled copies) under a [`Key`],
//! the learner receives it as a [`BatchItem`] and sends the key back with a new priority.
//! Plain data: the messages carry these types as they are.

pub mod batch;
pub mod transition;

pub use batch::{BatchItem, Key};
pub use transition::Transition;
