//! The nets as an actor runs them: the CPU inference form when they live on the CPU, burn's
//! own forward on any other device (a GPU's).

use burn::prelude::*;
use sim::{Primitive, ROTATIONS};

use policy::QMaps;

use crate::channels_last::for_acting;
use crate::error::QNetError;
use crate::geometry::Geometry;
use crate::inference::Inference;
use crate::input::NetInput;
use crate::qnets::QNets;

/// (Both boxed: the two are large and of different sizes.)
#[derive(Clone, Debug)]
pub enum ActingNets {
    Cpu(Box<Inference>),
    Device(Box<QNets>),
}

impl ActingNets {
    /// `nets` (in inference form: no autodiff, batch norms on their running statistics) as
    /// they act on their device: on a GPU laid out in full once, with their convolution
    /// weights as its convolutions read them ([`crate::channels_last`]).
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

    /// Q maps of one primitive for all rotations.
    pub fn all_rotations(
        &self,
        primitive: Primitive,
        input: &NetInput,
        geometry: &Geometry,
    ) -> Result<QMaps, QNetError> {
        match self {
            ActingNets::Cpu(inference) => inference.all_rotations(primitive, input, geometry),
            ActingNets::Device(nets) => nets.all_rotations(primitive, input, geometry),
        }
    }

    /// Q maps of each of `primitives` for all rotations, for each of `inputs` (several
    /// environments' at one decision), as one batch: in the CPU's inference form every input
    /// rotation of every input spread over the cores together, each computed once for all
    /// the primitives; on a device one forward pass of each net over them all.
    pub fn all_rotations_of_each<const N: usize>(
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

    /// The Q maps of one primitive at `rotations`, one `side x side` map after another.
    pub fn rotations(
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

/// Every rotation, in order.
pub(crate) fn every_rotation() -> Vec<u8> {
    (0..ROTATIONS).collect()
}

/// One primitive's maps of every rotation, one `side x side` map after another, as [`QMaps`].
pub(crate) fn q_maps(geometry: &Geometry, values: Vec<f32>) -> Result<QMaps, QNetError> {
    Ok(QMaps::new(ROTATIONS, geometry.side(), values)?)
}

/// `items` through `f`, stopping at the first error (arrays' own `try_map` is unstable).
pub(crate) fn try_map<A, B, const N: usize>(
    items: [A; N],
    f: impl FnMut(A) -> Result<B, QNetError>,
) -> Result<[B; N], QNetError> {
    let all: Vec<B> = items.into_iter().map(f).collect::<Result<_, _>>()?;
    Ok(all
        .try_into()
        .unwrap_or_else(|_| unreachable!("as many out as in")))
}
