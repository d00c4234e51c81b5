//! Observations as the buffer keeps them: compressed, and shared by the relabelled copies of
//! a step.
//!
//! A step's heightmaps are mostly flat and piecewise constant (blocks on a table), so they
//! compress well once laid out as planes: the red, green and blue bytes, the height's four
//! bytes each in a plane of its own (the exponent and high mantissa bytes repeat, the low
//! ones vary only at edges: a byte shuffle, as Blosc does), then the object ids. The planes
//! are one zstd frame ([`LEVEL`]; `pushgrasp bench buffer` measures the alternatives). A
//! packed observation carries an xxh3 hash of its compressed bytes, checked before they are
//! decompressed and when a snapshot is read, so a damaged record is named, never decoded
//! into a wrong scene.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use sim::{Heightmaps, PixelGrid};
use thiserror::Error;

use experience::Transition;

/// zstd's level: 1 packs a 112² step in about 0.1 ms to within a few percent of the bytes
/// of level 3, which takes twice as long; decoding costs the same at every level.
pub const LEVEL: i32 = 1;

/// Bytes per pixel in the planes: colour 3, height 4, id 1.
const PLANE_BYTES_PER_PIXEL: usize = 8;

/// A step's heightmaps, compressed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PackedObservation {
    grid: PixelGrid,
    /// One zstd frame of the planes.
    bytes: Box<[u8]>,
    /// xxh3 of `bytes`.
    hash: u64,
}

/// What the rings hold: one packed observation, shared by a step and its relabelled copies.
pub type SharedObservation = Arc<PackedObservation>;

/// A transition as the rings hold it.
pub type StoredTransition = Transition<SharedObservation>;

/// Why packed bytes could not become heightmaps again.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CorruptObservation {
    #[error("its bytes do not match their hash (damaged after they were packed)")]
    Hash,
    #[error("zstd cannot decode it: {0}")]
    Codec(String),
    #[error("it decodes to {found} bytes, a {side}x{side} grid needs {expected}")]
    Length {
        found: usize,
        expected: usize,
        side: usize,
    },
}

impl PackedObservation {
    /// Compresses `obs`.
    pub fn pack(obs: &Heightmaps) -> Self {
        let planes = planes(obs);
        let bytes = zstd::bulk::compress(&planes, LEVEL)
            .expect("zstd compresses any bytes into a buffer it sizes itself")
            .into_boxed_slice();
        Self {
            grid: obs.grid,
            hash: xxhash_rust::xxh3::xxh3_64(&bytes),
            bytes,
        }
    }

    /// The heightmaps, bit for bit as they were packed.
    pub fn unpack(&self) -> Result<Heightmaps, CorruptObservation> {
        self.check()?;
        let pixels = self.grid.len();
        let expected = pixels * PLANE_BYTES_PER_PIXEL;
        // One byte of room: a frame that decodes to more than a grid's planes is refused
        // instead of cut short.
        let planes = zstd::bulk::decompress(&self.bytes, expected + 1)
            .map_err(|e| CorruptObservation::Codec(e.to_string()))?;
        if planes.len() != expected {
            return Err(CorruptObservation::Length {
                found: planes.len(),
                expected,
                side: self.grid.side(),
            });
        }
        let (colour, rest) = planes.split_at(3 * pixels);
        let (height, ids) = rest.split_at(4 * pixels);
        let rgb: Vec<&[u8]> = colour.chunks_exact(pixels).collect();
        let bytes: Vec<&[u8]> = height.chunks_exact(pixels).collect();
        Ok(Heightmaps {
            grid: self.grid,
            colour: (0..pixels)
                .map(|i| [rgb[0][i], rgb[1][i], rgb[2][i]])
                .collect(),
            height: (0..pixels)
                .map(|i| f32::from_le_bytes([bytes[0][i], bytes[1][i], bytes[2][i], bytes[3][i]]))
                .collect(),
            ids: ids.to_vec(),
        })
    }

    /// Whether the compressed bytes are those that were packed.
    pub fn check(&self) -> Result<(), CorruptObservation> {
        if xxhash_rust::xxh3::xxh3_64(&self.bytes) == self.hash {
            Ok(())
        } else {
            Err(CorruptObservation::Hash)
        }
    }

    /// The compressed bytes, as they are stored and written to snapshots.
    pub fn compressed(&self) -> &[u8] {
        &self.bytes
    }
}

/// `transition` as the rings hold it: its observation packed, shared by nothing yet.
pub fn store(transition: Transition) -> StoredTransition {
    let obs = Arc::new(PackedObservation::pack(&transition.obs));
    transition.with_obs(obs)
}

/// The bytes that are compressed: each channel of `obs` as a plane of its own (see the module
/// documentation). Public so that the benchmark compresses the same bytes with other codecs.
pub fn planes(obs: &Heightmaps) -> Vec<u8> {
    let pixels = obs.grid.len();
    let mut planes = Vec::with_capacity(pixels * PLANE_BYTES_PER_PIXEL);
    for channel in 0..3 {
        planes.extend(obs.colour.iter().map(|rgb| rgb[channel]));
    }
    for byte in 0..4 {
        planes.extend(obs.height.iter().map(|h| h.to_le_bytes()[byte]));
    }
    planes.extend_from_slice(&obs.ids);
    planes
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> Heightmaps {
        let mut obs = Heightmaps::new(PixelGrid::new(0.004).unwrap());
        for i in 0..obs.ids.len() {
            if (i / 7) % 5 == 0 {
                obs.ids[i] = (i % 9) as u8 + 1;
                obs.height[i] = 0.025 + (i % 13) as f32 * 1e-4;
                obs.colour[i] = [i as u8, (i / 3) as u8, 200];
            }
        }
        // Values a float plane must keep bit for bit.
        obs.height[0] = -0.0;
        obs.height[1] = f32::MIN_POSITIVE;
        obs
    }

    #[test]
    fn observations_come_back_bit_for_bit() {
        let obs = scene();
        let packed = PackedObservation::pack(&obs);
        let back = packed.unpack().unwrap();
        assert_eq!(back.grid, obs.grid);
        assert_eq!(back.colour, obs.colour);
        assert_eq!(back.ids, obs.ids);
        let bits = |h: &[f32]| h.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&back.height), bits(&obs.height));
        assert!(packed.compressed().len() < obs.ids.len() * PLANE_BYTES_PER_PIXEL / 4);
    }

    #[test]
    fn damaged_bytes_are_refused_not_decoded() {
        let mut packed = PackedObservation::pack(&scene());
        packed.bytes[10] ^= 0x40;
        assert_eq!(packed.unpack(), Err(CorruptObservation::Hash));
        // Bytes that match their hash but are not a frame of this grid's planes.
        packed.bytes = zstd::bulk::compress(&[1, 2, 3], LEVEL).unwrap().into();
        packed.hash = xxhash_rust::xxh3::xxh3_64(&packed.bytes);
        assert!(matches!(
            packed.unpack(),
            Err(CorruptObservation::Length { found: 3, .. })
        ));
        packed.bytes = vec![0; 16].into();
        packed.hash = xxhash_rust::xxh3::xxh3_64(&packed.bytes);
        assert!(matches!(packed.unpack(), Err(CorruptObservation::Codec(_))));
    }
}
