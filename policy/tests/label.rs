//! Bootstrap labels: the fixed point a reliable grasp converges to, and the clamp on
//! bootstrap values.

use policy::{grasp_label, push_label};

/// The paper's discount.
const GAMMA: f32 = 0.5;

#[test]
fn labels_converge_to_the_fixed_point_q_star_sits_below() {
    let gamma = GAMMA;
    let mut q = 0.0;
    for _ in 0..40 {
        q = grasp_label(1.0, true, Some(q), gamma);
    }
    assert!((q - 2.0).abs() < 1e-4 && q > 1.8, "{q}");
    assert_eq!(
        grasp_label(0.0, false, Some(1.9), gamma),
        0.0,
        "no future after a failure"
    );
    assert_eq!(
        grasp_label(1.0, true, None, gamma),
        1.0,
        "no future after the last object"
    );
    assert_eq!(push_label(0.5, Some(1.0), gamma), 1.0);
    assert_eq!(push_label(-0.5, None, gamma), -0.5);
}

#[test]
fn bootstrap_values_are_clamped_to_what_a_state_can_be_worth() {
    let gamma = GAMMA;
    // An overestimated next value counts as the fixed point 1 / (1 - gamma) = 2.
    assert_eq!(grasp_label(1.0, true, Some(2.9), gamma), 2.0);
    assert_eq!(grasp_label(1.0, true, Some(-0.3), gamma), 1.0);
    assert_eq!(push_label(0.0, Some(2.9), gamma), 1.0);
    // A push's next state may be worth less than nothing (pushes that change nothing).
    assert_eq!(push_label(0.0, Some(-0.6), gamma), -0.3);
    assert_eq!(push_label(0.0, Some(-5.0), gamma), -0.5);
}
