//! What every form of the nets gives an actor: Q maps of a primitive at some rotations or at
//! all of them, for one input or several at once. [`QNets`](crate::QNets) (burn's forward,
//! on any device), [`Inference`](crate::Inference) (the CPU's inference form) and
//! [`ActingNets`](crate::ActingNets) (whichever of the two the nets' device calls for) each
//! compute the batch their own way; the rest follows from it here, once.

use sim::{Primitive, ROTATIONS};

use policy::QMaps;

use crate::error::QNetError;
use crate::geometry::Geometry;
use crate::input::NetInput;

/// Q maps of the nets' primitives over the 16 rotations.
pub trait RotatedQMaps {
    /// The Q maps of one primitive at `rotations`, one `side x side` map after another.
    fn rotations(
        &self,
        primitive: Primitive,
        input: &NetInput,
        rotations: &[u8],
        geometry: &Geometry,
    ) -> Result<Vec<f32>, QNetError>;

    /// Q maps of each of `primitives` for all rotations, for each of `inputs` (several
    /// environments' at one decision), as one batch.
    fn all_rotations_of_each<const N: usize>(
        &self,
        primitives: [Primitive; N],
        inputs: &[&NetInput],
        geometry: &Geometry,
    ) -> Result<Vec<[QMaps; N]>, QNetError>;

    /// Q maps of each of `primitives` for all rotations of one input, in one batch (an actor
    /// that pushes scores both nets on every decision).
    fn all_rotations_of<const N: usize>(
        &self,
        primitives: [Primitive; N],
        input: &NetInput,
        geometry: &Geometry,
    ) -> Result<[QMaps; N], QNetError> {
        let mut maps = self.all_rotations_of_each(primitives, &[input], geometry)?;
        Ok(maps.pop().expect("one input, one set of maps"))
    }

    /// Q maps of one primitive for all rotations.
    fn all_rotations(
        &self,
        primitive: Primitive,
        input: &NetInput,
        geometry: &Geometry,
    ) -> Result<QMaps, QNetError> {
        let [maps] = self.all_rotations_of([primitive], input, geometry)?;
        Ok(maps)
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
