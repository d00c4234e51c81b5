//! Which actor an environment is, and the seeds and episode ids derived from it.

use serde::{Deserialize, Serialize};

/// Which actor this is: its index in the run and how many times that index was started.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ActorId {
    pub index: u32,
    pub incarnation: u32,
}

impl ActorId {
    /// The seed of this actor's scenes and exploration, derived from the run seed.
    pub fn seed(self, run_seed: u64) -> u64 {
        run_seed
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .wrapping_add(u64::from(self.index) << 20)
            .wrapping_add(u64::from(self.incarnation))
    }

    /// Episode ids unique across the run: index, incarnation, then a counter.
    pub(super) fn episode(self, counter: u64) -> u64 {
        (u64::from(self.index) << 48) | (u64::from(self.incarnation) << 32) | counter
    }

    /// The ids of trial grasps, apart from the episodes' by the counter's top bit.
    pub(super) fn trial(self, counter: u64) -> u64 {
        self.episode(counter | TRIAL_BIT)
    }
}

/// Set in the counter part of a trial grasp's episode id.
const TRIAL_BIT: u64 = 1 << 31;
