//! How far apart two computations of the same values are: the CPU against a GPU, the
//! inference form against burn's forward, ours against a peer's.

use serde::Serialize;

#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Difference {
    /// The largest absolute difference of one value.
    pub max_abs: f32,
    /// `max_abs` over the reference's largest magnitude: relative to the maps' scale, since
    /// a value near zero makes an element-wise ratio meaningless.
    pub max_rel: f32,
}

/// The larger of two differences, NaN when either is: `f32::max` drops a NaN, which would
/// let maps of NaN agree with anything.
pub fn worst(a: f32, b: f32) -> f32 {
    if a.is_nan() || b.is_nan() {
        f32::NAN
    } else {
        a.max(b)
    }
}

impl Difference {
    /// `ours` against `reference`, element by element (the lengths must match; an all-zero
    /// reference gives an infinite or undefined `max_rel`, never a passing one).
    pub fn between(ours: &[f32], reference: &[f32]) -> Self {
        assert_eq!(
            ours.len(),
            reference.len(),
            "compared values differ in count"
        );
        let scale = reference.iter().fold(0f32, |m, v| worst(m, v.abs()));
        let max_abs = ours
            .iter()
            .zip(reference)
            .fold(0f32, |m, (a, b)| worst(m, (a - b).abs()));
        Self {
            max_abs,
            max_rel: max_abs / scale,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_relative_difference_is_to_the_reference_scale() {
        let d = Difference::between(&[1.0, -2.5, 0.0], &[1.0, -2.0, 0.1]);
        assert_eq!(d.max_abs, 0.5);
        assert_eq!(d.max_rel, 0.25);
        assert!(Difference::between(&[0.0], &[0.0]).max_rel.is_nan());
        // A NaN on either side is no agreement.
        assert!(
            Difference::between(&[1.0, f32::NAN], &[1.0, 2.0])
                .max_rel
                .is_nan()
        );
        assert!(
            Difference::between(&[1.0, 2.0], &[f32::NAN, 2.0])
                .max_rel
                .is_nan()
        );
    }
}
