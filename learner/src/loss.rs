//! The losses of a training step at the executed pixels: the Q values' Huber loss against
//! their labels and the grasp outcome head's cross-entropy, each weighted by the replay's
//! importance-sampling weights and summed.

use burn::prelude::*;
use burn::tensor::activation::log_sigmoid;

/// The weighted Huber loss of the Q values at the executed pixels against their labels,
/// summed. Each residual's loss as `c (|r| - c / 2)` with `c = min(|r|, delta)`: `r^2 / 2`
/// within delta, `delta (|r| - delta / 2)` past it, as burn's `HuberLoss`, whose two-sided
/// clamp and selection made its forward 12 kernels on a GPU where this one makes 7.
pub fn executed_pixel_loss(
    q: Tensor<1>,
    labels: &[f32],
    weights: &[f32],
    huber_delta: f32,
) -> Tensor<1> {
    let size = (q.clone() - per_item(labels, &q)).abs();
    let capped = size.clone().clamp_max(huber_delta);
    let huber = capped.clone() * (size - capped.mul_scalar(0.5));
    (huber * per_item(weights, &q)).sum()
}

/// The weighted cross-entropy of the outcome logits at the executed pixels against
/// `succeeded` (1 or 0 each), summed.
pub fn outcome_loss(logits: Tensor<1>, succeeded: &[f32], weights: &[f32]) -> Tensor<1> {
    let y = per_item(succeeded, &logits);
    let x = logits;
    // -(y log sigmoid(x) + (1 - y) log sigmoid(-x)), without forming sigmoid(x).
    let entropy = -(log_sigmoid(x.clone()) * y.clone() + log_sigmoid(-x.clone()) * (-y + 1.0));
    (entropy * per_item(weights, &x)).sum()
}

/// One value per item of `like`, as a tensor on its device.
fn per_item(values: &[f32], like: &Tensor<1>) -> Tensor<1> {
    Tensor::from_data(
        TensorData::new(values.to_vec(), like.dims()),
        &like.device(),
    )
}
