//! Helper of the push guards' tests: the policy passing over a push its guard closes.

use sim::{Action, Heightmaps, ObjectId, Primitive};

use policy::{PolicyConfig, push_region};

use crate::masks::{chosen, index};

/// Asserts that the policy, greedy, chooses `closed` when its push Q is the highest and no
/// guard is on, and under `guarded` (its landing guard reading `landing_view` where given)
/// chooses another push, one its push region holds where the region does not hold `closed`.
pub fn passes_over(
    obs: &Heightmaps,
    landing_view: Option<&Heightmaps>,
    goal: ObjectId,
    push_length: f32,
    closed: &Action,
    guarded: &PolicyConfig,
) {
    let chosen = |policy: &PolicyConfig| {
        chosen(obs, landing_view, goal, push_length, closed, policy, 0.0, 0)
    };
    assert_eq!(chosen(&PolicyConfig::default()), *closed);
    let action = chosen(guarded);
    assert_eq!(action.primitive, Primitive::Push);
    assert_ne!(action, *closed);
    let region = push_region(obs, landing_view, goal, guarded, push_length);
    assert!(region[index(obs, &action)]);
    assert!(!region[index(obs, closed)]);
}
