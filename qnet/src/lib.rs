//! The goal-conditioned push and grasp Q-networks, shared by the actors (inference over all
//! rotations) and the learner (training on the executed rotation).
//!
//! Each primitive has one fully convolutional net: parallel trunks over the colour, depth and
//! goal-mask planes, concatenated, then the paper's head, giving one Q map per rotation. The
//! input is rotated by -theta (padded so no corner is lost) and each output rotated back by
//! +theta, so Q map k scores the action at angle k x 22.5 degrees. The same code runs on the
//! CPU backend (burn-flex, the default) and, with the `wgpu` feature, on a GPU; on the CPU,
//! actors act through the nets' inference form ([`Inference`]), the same function computed
//! several times faster.

pub mod acting;
pub mod agreement;
pub mod batch_norm;
mod channels_last;
pub mod config;
#[cfg(feature = "wgpu")]
pub mod cube_outputs;
pub mod device;
pub mod equivariant;
pub mod error;
mod fresh;
pub mod gemm_conv;
pub mod geometry;
mod host_copy;
pub mod inference;
pub mod input;
pub mod kernels;
pub mod layers;
pub mod net;
pub mod plane_sums;
pub mod qnets;
pub mod rotations;
mod weight_layout;

pub use acting::ActingNets;
pub use agreement::Difference;
/// The device the nets live on (burn's).
pub use burn::tensor::Device;
pub use config::QNetConfig;
pub use device::{Adapter, Backend, OpenDevice, tune_cache};
pub use error::QNetError;
pub use geometry::Geometry;
pub use inference::Inference;
pub use input::NetInput;
pub use layers::NetLayers;
pub use net::PrimitiveNet;
pub use qnets::QNets;
pub use rotations::RotatedQMaps;

/// What the unit tests share.
#[cfg(test)]
mod testing {
    /// Asserts `ours` equals `reference` within `tolerance` of the reference's largest
    /// magnitude (which must not be zero, so an all-zero pair cannot pass).
    pub fn assert_close(ours: &[f32], reference: &[f32], tolerance: f32, what: &str) {
        let d = crate::Difference::between(ours, reference);
        assert!(
            d.max_rel <= tolerance,
            "{what} differs by {} ({} of the reference's scale)",
            d.max_abs,
            d.max_rel
        );
    }

    /// A `side x side` input of varied values in [-1, 1] with a binary mask, no scene needed.
    pub fn patterned_input(side: usize) -> crate::NetInput {
        let plane = |planes: usize| {
            let n = planes * side * side;
            (0..n)
                .map(|i| ((i * 7919) % 101) as f32 / 50.0 - 1.0)
                .collect()
        };
        crate::NetInput {
            side,
            colour: plane(3),
            depth: plane(1),
            mask: plane(1)
                .into_iter()
                .map(|v: f32| f32::from(v > 0.0))
                .collect(),
        }
    }
}
