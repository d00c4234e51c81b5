//! The learner's own bootstrap values of next states (Double DQN, van Hasselt et al. 2016),
//! computed when a sample is drawn instead of frozen by the weights its actor acted with: the
//! next state's best action of the primitive the policy took there, where that primitive may
//! act, chosen by the trained nets and valued by target nets, a copy of the trained nets
//! taken every `[learning] target_update_every` updates. Choosing with one set of weights
//! and valuing with another keeps the maximum over thousands of pixels from valuing its own
//! noise.

use qnet::{ActingNets, Geometry, NetInput, QNets, RotatedQMaps};
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
/// `target` (both in inference form). The trained nets score every state of a primitive in
/// one batch.
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
    let mut values = vec![0.0; states.len()];
    for primitive in [Primitive::Push, Primitive::Grasp] {
        let of: Vec<usize> = (0..states.len())
            .filter(|&i| states[i].primitive == primitive)
            .collect();
        if of.is_empty() {
            continue;
        }
        let inputs: Vec<&NetInput> = of.iter().map(|&i| &states[i].input).collect();
        let maps = trained.all_rotations_of_each([primitive], &inputs, geometry)?;
        for (&i, [maps]) in of.iter().zip(maps) {
            let state = &states[i];
            let (_, rotation, row, col) = maps
                .best_where(&state.allowed)
                .ok_or(LearnerError::NoQValue(primitive))?;
            let map = target.rotations(primitive, &state.input, &[rotation], geometry)?;
            values[i] = map[row * geometry.side() + col];
        }
    }
    Ok(values)
}
