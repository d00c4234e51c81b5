//! How the replay names a stored transition, and a sampled one.

use serde::{Deserialize, Serialize};
use sim::Primitive;

use crate::observation::{CorruptObservation, StoredTransition};
use crate::transition::Transition;

/// A stable name for a stored item: priority updates carry it back from the learner.
/// `generation` counts the inserts into the primitive's ring, so once a slot is overwritten
/// the old key no longer matches and its update is ignored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Key {
    pub primitive: Primitive,
    pub slot: u32,
    pub generation: u64,
}

/// One sampled transition with what the learner needs to weigh it and update its priority:
/// the replay lends its stored transitions, a message carries them owned and still packed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BatchItem<T = Transition> {
    pub key: Key,
    /// The importance-sampling weight (N P(i))^-beta divided by the batch's largest.
    pub weight: f32,
    pub transition: T,
}

impl BatchItem<StoredTransition> {
    /// The item with its observations decompressed, as the learner trains on it.
    pub fn unpack(&self) -> Result<BatchItem, CorruptObservation> {
        Ok(BatchItem {
            key: self.key,
            weight: self.weight,
            transition: self.transition.clone().try_map_obs(|obs| obs.unpack())?,
        })
    }
}
