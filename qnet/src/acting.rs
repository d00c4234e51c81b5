//! The nets as an actor runs them: the CPU inference form when they live on the CPU, burn's
//! own forward on any other device (a GPU's).

use burn::prelude::*;
use sim::{Primitive, ROTATIONS};

use policy::QMaps;

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
    /// they act on their device.
    pub fn new(nets: &QNets) -> Result<Self, QNetError> {
        Ok(if nets.device() == Device::flex() {
            ActingNets::Cpu(Box::new(Inference::new(nets)?))
        } else {
            ActingNets::Device(Box::new(nets.clone()))
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

/// The maps of every rotation as [`QMaps`], from a function giving the maps of the rotations
/// asked for.
pub(crate) fn every_rotation(
    geometry: &Geometry,
    maps: impl FnOnce(&[u8]) -> Result<Vec<f32>, QNetError>,
) -> Result<QMaps, QNetError> {
    let rotations: Vec<u8> = (0..ROTATIONS).collect();
    Ok(QMaps::new(ROTATIONS, geometry.side(), maps(&rotations)?)?)
}
