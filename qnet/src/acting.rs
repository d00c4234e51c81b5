//! The nets as an actor runs them: the CPU inference form when they live on the CPU, burn's
//! own forward on any other device (a GPU's).

use burn::prelude::*;
use sim::Primitive;

use policy::QMaps;

use crate::channels_last::for_acting;
use crate::error::QNetError;
use crate::geometry::Geometry;
use crate::inference::Inference;
use crate::input::NetInput;
use crate::qnets::QNets;
use crate::rotations::RotatedQMaps;

/// (Both boxed: the two are large and of different sizes.)
#[derive(Clone, Debug)]
pub enum ActingNets {
    Cpu(Box<Inference>),
    Device(Box<QNets>),
}

impl ActingNets {
    /// `nets` (in inference form: no autodiff, batch norms on their running statistics) as
    /// they act on their device: on a GPU laid out in full once, with their convolution
    /// weights as its convolutions read them (`channels_last`).
    pub fn new(nets: &QNets) -> Result<Self, QNetError> {
        Ok(if nets.device() == Device::flex() {
            ActingNets::Cpu(Box::new(Inference::new(nets)?))
        } else {
            ActingNets::Device(Box::new(QNets {
                push: for_acting(&nets.push),
                grasp: for_acting(&nets.grasp),
            }))
        })
    }
}

/// In the CPU's inference form every input rotation of every input spread over the cores
/// together, each computed once for all the primitives; on a device one forward pass of each
/// net over them all.
impl RotatedQMaps for ActingNets {
    fn all_rotations_of_each<const N: usize>(
        &self,
        primitives: [Primitive; N],
        inputs: &[&NetInput],
        geometry: &Geometry,
    ) -> Result<Vec<[QMaps; N]>, QNetError> {
        match self {
            ActingNets::Cpu(inference) => {
                inference.all_rotations_of_each(primitives, inputs, geometry)
            }
            ActingNets::Device(nets) => nets.all_rotations_of_each(primitives, inputs, geometry),
        }
    }

    fn rotations(
        &self,
        primitive: Primitive,
        input: &NetInput,
        rotations: &[u8],
        geometry: &Geometry,
    ) -> Result<Vec<f32>, QNetError> {
        match self {
            ActingNets::Cpu(inference) => {
                inference.rotations(primitive, input, rotations, geometry)
            }
            ActingNets::Device(nets) => nets.rotations(primitive, input, rotations, geometry),
        }
    }
}
