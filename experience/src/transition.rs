//! One stored step: what the learner needs to train on it (observation, goal, action, label
//! inputs) and what relabelling needs (the episode, the step index, the object grasped).

use std::convert::Infallible;

use serde::{Deserialize, Serialize};
use sim::{Action, Heightmaps, ObjectId, Primitive};

/// A step of an episode as the roles exchange it.
///
/// The goal mask is not stored: it is `obs.goal_mask(goal)`, derived from the stored id map,
/// so a relabelled copy needs only a different `goal`. `O` is the observation's form: the
/// heightmaps themselves, or what the buffer keeps of them (compressed, shared by the
/// relabelled copies of one step).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Transition<O = Heightmaps> {
    /// The episode, unique across every actor of a run (the wiring combines actor and
    /// episode counter); steps of one episode are assembled and relabelled together.
    pub episode: u64,
    /// The step's index within its episode, from 0 without gaps.
    pub step: u32,
    /// The goal this copy is stored for.
    pub goal: ObjectId,
    /// The observation the action was chosen on.
    pub obs: O,
    pub action: Action,
    /// The reward for `goal`.
    pub reward: f32,
    /// The object the action grasped, if it was a grasp that held one.
    pub grasped: Option<ObjectId>,
    /// The actor's bootstrap value of the next state, `None` when the scene ended with this
    /// step; the learner turns reward and next value into a label (`policy::label`).
    pub next_value: Option<f32>,
    /// The episode's next step, which the buffer attaches to each push it stores (`None`
    /// from actors, for grasps, and where the episode's next step never arrived): what a
    /// learner that values next states itself needs (`[learning] target_update_every`).
    pub next: Option<Successor<O>>,
}

/// The step after a push, as a learner values it: the observation it was chosen on and its
/// primitive (the value of a state is that of the primitive the policy took there).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Successor<O = Heightmaps> {
    pub obs: O,
    pub primitive: Primitive,
}

impl<O> Transition<O> {
    /// Push or grasp: which storage the step belongs to.
    pub fn primitive(&self) -> Primitive {
        self.action.primitive
    }

    /// Whether this is a grasp that picked this copy's goal.
    pub fn goal_grasped(&self) -> bool {
        self.grasped == Some(self.goal)
    }

    /// The same step with its observations (its own and its successor's) in another form.
    pub fn map_obs<P>(self, mut f: impl FnMut(O) -> P) -> Transition<P> {
        match self.try_map_obs(|obs| Ok::<P, Infallible>(f(obs))) {
            Ok(mapped) => mapped,
            Err(never) => match never {},
        }
    }

    /// [`Self::map_obs`] with a conversion that can fail.
    pub fn try_map_obs<P, E>(
        self,
        mut f: impl FnMut(O) -> Result<P, E>,
    ) -> Result<Transition<P>, E> {
        let next = match self.next {
            Some(Successor { obs, primitive }) => Some(Successor {
                obs: f(obs)?,
                primitive,
            }),
            None => None,
        };
        Ok(Transition {
            episode: self.episode,
            step: self.step,
            goal: self.goal,
            obs: f(self.obs)?,
            action: self.action,
            reward: self.reward,
            grasped: self.grasped,
            next_value: self.next_value,
            next,
        })
    }
}

impl Transition {
    /// The goal mask the learner feeds the nets: the goal's pixels in the stored id map.
    pub fn goal_mask(&self) -> Vec<bool> {
        self.obs.goal_mask(self.goal)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::PixelGrid;

    fn step(primitive: Primitive, goal: ObjectId, grasped: Option<ObjectId>) -> Transition {
        Transition {
            episode: 0,
            step: 0,
            goal,
            obs: Heightmaps::new(PixelGrid::new(0.004).unwrap()),
            action: Action {
                primitive,
                rotation: 0,
                row: 0,
                col: 0,
            },
            reward: 0.0,
            grasped,
            next_value: Some(1.5),
            next: None,
        }
    }

    #[test]
    fn the_goal_mask_comes_from_the_stored_ids() {
        let mut t = step(Primitive::Grasp, 7, None);
        t.obs.ids[5] = 7;
        t.obs.ids[6] = 2;
        let mask = t.goal_mask();
        assert_eq!(mask.iter().filter(|m| **m).count(), 1);
        assert!(mask[5]);
    }
}
