//! Errors the policy side reports, each naming what was wrong.

use sim::Primitive;

/// What can go wrong between Q maps and a decision.
#[derive(Debug, thiserror::Error)]
pub enum PolicyError {
    /// Q values whose number is not rotations x side x side.
    #[error(
        "Q maps hold {got} values, but {rotations} rotations of {side} x {side} need {expected}"
    )]
    QMapsLength {
        rotations: u8,
        side: usize,
        expected: usize,
        got: usize,
    },
    /// Q maps that do not cover the observation at the simulator's rotations.
    #[error(
        "{primitive:?} Q maps are {rotations} rotations of {side} x {side}, but the policy needs {want_rotations} of {want_side} x {want_side}"
    )]
    QMapsShape {
        primitive: Primitive,
        rotations: u8,
        side: usize,
        want_rotations: u8,
        want_side: usize,
    },
    /// A primitive with no usable Q value where it may act (the network produced NaN).
    #[error("{0:?} Q maps are NaN everywhere the action may go")]
    NoQValue(Primitive),
    /// An exploration rate that is not a probability.
    #[error("exploration rate {0} is not in [0, 1]")]
    Epsilon(f32),
}
