//! The learner's own bootstrap values of next states (Double DQN, van Hasselt et al. 2016),
//! computed when a sample is drawn instead of frozen by the weights its actor acted with: the
//! next state's best action of the primitive the policy took there, where that primitive may
//! act, chosen by the trained nets and valued by target nets, a copy of the trained nets
//! taken every `[learning] target_update_every` updates. Choosing with one set of weights
//! and valuing with another keeps the maximum over thousands of pixels from valuing its own
//! noise.

use qnet::{ActingNets, Geometry, NetInput, QNets};
use sim::Primitive;

use crate::error::LearnerError;

/// A next state to value.
#[derive(Clone, Debug)]
pub struct NextState {
    /// The next observation with the sample's goal.
    pub input: NetInput,
    /// The primitive the policy took there: a state is worth its best action of that one.
    pub primitive: Primitive,
    /// Where that primitive may act (`policy::grasp_region`, `policy::valid_push_starts`),
    /// row-major, `side * side`.
    pub allowed: Vec<bool>,
}

/// The value of each state in `states`: its best allowed action under `trained`, valued by
/// `target` (both in inference form).
pub(crate) fn double_q_values(
    trained: &QNets,
    target: &QNets,
    states: &[NextState],
    geometry: &Geometry,
) -> Result<Vec<f32>, LearnerError> {
    if states.is_empty() {
        return Ok(Vec::new());
    }
    let (trained, target) = (ActingNets::new(trained)?, ActingNets::new(target)?);
    states
        .iter()
        .map(|state| {
            let maps = trained.all_rotations(state.primitive, &state.input, geometry)?;
            let (_, rotation, row, col) = maps
                .best_where(&state.allowed)
                .ok_or(LearnerError::NoQValue(state.primitive))?;
            let map = target.rotations(state.primitive, &state.input, &[rotation], geometry)?;
            Ok(map[row * geometry.side() + col])
        })
        .collect()
}
