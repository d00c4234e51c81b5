//! Episode assembly and goal relabelling, as the paper says: when an episode's grasp picks a
//! non-goal object g', that grasp is stored again with goal g' and its reward recomputed for
//! g' (1), and so are the episode's pushes before it ("such a push sequence is beneficial for
//! its grasping").
//!
//! A copy differs from its original only in `goal` and `reward`: goal masks are derived from
//! the stored id maps (`Transition::goal_mask`), so nothing of a later scene is needed.
//!
//! The reward of a relabelled push is the run's push reward for g'
//! ([`PushReward::relabelled`]), from change detection around g' recomputed here from the
//! stored observations (before: the push's own; after: the next step's). Its bootstrap value
//! is kept as the actor computed it (for the original goal): the buffer cannot evaluate a net.
//! A learner that values next states itself (`[learning] target_update_every`) values it
//! for g' from the next step stored with it.
//!
//! Pushes after the relabelled grasp, and pushes whose observation does not show g' (its goal
//! mask would be empty, which the policy never acts on), are not copied.
//!
//! An ending episode's observations are packed here, once per step (in parallel): a copy
//! shares its original's packed observation. Each push is stored with its next step's
//! observation and primitive (shared, not copied), so a learner can value the next state
//! itself, for a relabelled copy with the copy's goal.

use std::collections::BTreeMap;

use policy::{GRASP_REWARD, PushReward};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sim::measure::detect_change;
use sim::{ObjectId, Primitive};

use experience::{Successor, Transition};

use crate::error::AssembleError;
use experience::{PackedObservation, StoredTransition};

/// A step waiting for its episode to end, with the actor's initial priority (|TD error|).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pending {
    pub transition: Transition,
    pub priority: Option<f64>,
}

/// A transition ready to store, its observation packed.
#[derive(Clone, Debug, PartialEq)]
pub struct Ready {
    pub transition: StoredTransition,
    /// The actor's priority for originals; `None` (the buffer's largest priority, as for any
    /// unseen experience) for relabelled copies, whose TD error nobody has computed.
    pub priority: Option<f64>,
    /// Whether this is a relabelled copy.
    pub relabelled: bool,
}

/// Collects each open episode's steps until it ends.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EpisodeAssembler {
    open: BTreeMap<u64, BTreeMap<u32, Pending>>,
    relabelled: u64,
}

impl EpisodeAssembler {
    /// No open episodes.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a step to its episode; a step index received twice, or a priority that is not a
    /// finite number >= 0, is refused.
    pub fn add(
        &mut self,
        transition: Transition,
        priority: Option<f64>,
    ) -> Result<(), AssembleError> {
        let (episode, step) = (transition.episode, transition.step);
        if let Some(priority) = priority.filter(|p| !(p.is_finite() && *p >= 0.0)) {
            return Err(AssembleError::BadPriority {
                episode,
                step,
                priority,
            });
        }
        let steps = self.open.entry(episode).or_default();
        if steps.contains_key(&step) {
            return Err(AssembleError::DuplicateStep { episode, step });
        }
        steps.insert(
            step,
            Pending {
                transition,
                priority,
            },
        );
        Ok(())
    }

    /// Episodes with steps and no end yet.
    pub fn open_episodes(&self) -> usize {
        self.open.len()
    }

    /// Relabelled copies produced so far.
    pub fn relabelled(&self) -> u64 {
        self.relabelled
    }

    /// Ends an episode whose final grasp picked `grasped` (or nothing), and returns its steps
    /// in order, followed by the relabelled copies the paper implies when `relabelling` gives
    /// the run's push reward (`None`: no relabelling). On an error the episode stays open,
    /// untouched, so its steps can still be [`flush`](Self::flush)ed.
    pub fn end(
        &mut self,
        episode: u64,
        grasped: Option<ObjectId>,
        relabelling: Option<PushReward>,
    ) -> Result<Vec<Ready>, AssembleError> {
        let steps = self
            .open
            .get(&episode)
            .ok_or(AssembleError::UnknownEpisode(episode))?;
        if let Some(missing) = (0..)
            .zip(steps.keys())
            .find(|(i, s)| i != *s)
            .map(|(i, _)| i)
        {
            return Err(AssembleError::MissingStep { episode, missing });
        }
        let ordered: Vec<&Transition> = steps.values().map(|p| &p.transition).collect();
        let copies = match grasped {
            Some(object) => relabel(&ordered, object, relabelling)
                .ok_or(AssembleError::GraspNotFound { episode, object })?,
            None => Vec::new(),
        };
        self.relabelled += copies.len() as u64;
        let mut ready = self.flush(episode);
        let copies = copies.into_iter().map(|copy| {
            let original = &ready[copy.of].transition;
            Ready {
                transition: Transition {
                    goal: copy.goal,
                    reward: copy.reward,
                    obs: original.obs.clone(),
                    next: original.next.clone(),
                    ..*original
                },
                priority: None,
                relabelled: true,
            }
        });
        let copies: Vec<Ready> = copies.collect();
        ready.extend(copies);
        Ok(ready)
    }

    /// Closes an episode without relabelling (an actor that died mid-episode) and returns its
    /// steps in order, so none is lost; an unknown episode gives nothing. Each push that has
    /// its next step here gets it as its [`Successor`].
    pub fn flush(&mut self, episode: u64) -> Vec<Ready> {
        let steps: Vec<Pending> = self
            .open
            .remove(&episode)
            .into_iter()
            .flat_map(|steps| steps.into_values())
            .collect();
        let mut ready: Vec<Ready> = steps
            .into_par_iter()
            .map(|p| Ready {
                transition: p.transition.map_obs(|obs| PackedObservation::pack(&obs)),
                priority: p.priority,
                relabelled: false,
            })
            .collect();
        for i in 1..ready.len() {
            let (before, after) = ready.split_at_mut(i);
            let (t, next) = (&mut before[i - 1].transition, &after[0].transition);
            if t.primitive() == Primitive::Push && next.step == t.step + 1 {
                t.next = Some(Successor {
                    obs: next.obs.clone(),
                    primitive: next.primitive(),
                });
            }
        }
        ready
    }
}

/// A relabelled copy of the episode's step `of`: another goal, another reward.
struct Copy {
    of: usize,
    goal: ObjectId,
    reward: f32,
}

/// The relabelled copies of a contiguous episode (`steps[i].step == i`) whose last grasp of
/// `object` is the episode's outcome, none without `relabelling`; `None` when no grasp
/// picked `object`.
fn relabel(
    steps: &[&Transition],
    object: ObjectId,
    relabelling: Option<PushReward>,
) -> Option<Vec<Copy>> {
    let grasp = steps
        .iter()
        .rposition(|t| t.primitive() == Primitive::Grasp && t.grasped == Some(object))?;
    let Some(push_reward) = relabelling.filter(|_| steps[grasp].goal != object) else {
        // The goal itself was grasped (the original already says so), or no relabelling.
        return Some(Vec::new());
    };
    let mut copies = Vec::new();
    for (of, (t, next)) in steps[..grasp].iter().zip(&steps[1..=grasp]).enumerate() {
        if t.primitive() != Primitive::Push || t.goal == object || !t.obs.ids.contains(&object) {
            continue;
        }
        let change = detect_change(&t.obs, &next.obs, object);
        copies.push(Copy {
            of,
            goal: object,
            reward: push_reward.relabelled(&change),
        });
    }
    copies.push(Copy {
        of: grasp,
        goal: object,
        // The grasp reward for g': it picked g'.
        reward: GRASP_REWARD,
    });
    Some(copies)
}
