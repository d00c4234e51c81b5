//! Bootstrap labels, kept consistent with the Q* threshold.
//!
//! As the original, a grasp's label bootstraps even across a success: label = R + gamma x the
//! next scene's best goal grasp Q, the future term being 0 after a failed grasp or when the
//! scene ends. A reliably successful grasp therefore converges to 1 / (1 - gamma) = 2.0, and
//! Q* = 1.8 sits just below that fixed point. A push bootstraps on the push Q of the scene it
//! leaves for the next push, or on the goal's grasp Q when a grasp comes next.

/// The label of a grasp: `reward` plus, after a success, the discounted value of the next
/// scene (`None` when the scene ended).
pub fn grasp_label(reward: f32, succeeded: bool, next_value: Option<f32>, gamma: f32) -> f32 {
    match (succeeded, next_value) {
        (true, Some(next)) => reward + gamma * next,
        _ => reward,
    }
}

/// The label of a push: `reward` plus the discounted value of the next state (`None` when
/// the episode ended with it).
pub fn push_label(reward: f32, next_value: Option<f32>, gamma: f32) -> f32 {
    reward + gamma * next_value.unwrap_or(0.0)
}
