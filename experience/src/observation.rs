//! Observations as the buffer keeps them and the learner receives them: compressed, and
//! shared by the relabelled copies of a step. Batches travel packed (a twentieth of the
//! bytes) and are unpacked by the learner, which needs the heightmaps.
//!
//! A step's heightmaps are mostly flat and piecewise constant (blocks on a table), so they
//! compress well once laid out as planes: the red, green and blue bytes, the height's four
//! bytes each in a plane of its own (the exponent and high mantissa bytes repeat, the low
//! ones vary only at edges: a byte shuffle, as Blosc does), then the object ids. The planes
//! are one zstd frame ([`LEVEL`]; `pushgrasp bench buffer` measures the alternatives). A
//! packed observation carries an xxh3 hash of its compressed bytes, checked before they are
//! decompressed and when a snapshot is read, so a damaged record is named, never decoded
//! into a wrong scene.
//!
//! A packed observation is one shared allocation (its header, then the frame): relabelled
//! copies of a step hold the same one, and a small step costs one allocation, not two.

use std::borrow::Cow;
use std::cell::RefCell;
use std::sync::Arc;

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use sim::{Heightmaps, PixelGrid};
use thiserror::Error;
use zstd::bulk::{Compressor, Decompressor};

use crate::transition::Transition;

/// zstd's level: 1 packs a 112² step in about 0.1 ms to within a few percent of the bytes
/// of level 3, which takes a third longer; decoding costs the same at every level.
pub const LEVEL: i32 = 1;

/// Bytes per pixel in the planes: colour 3, height 4, id 1.
const PLANE_BYTES_PER_PIXEL: usize = 8;

/// The header before the frame: the xxh3 hash of the frame (u64), the grid's pixel size
/// (f32), little-endian.
const HEADER: usize = 8 + 4;

thread_local! {
    /// zstd's contexts, one of each per thread: making one per call took half the time of
    /// packing a small step.
    static CODEC: RefCell<(Compressor<'static>, Decompressor<'static>)> = RefCell::new((
        Compressor::new(LEVEL).expect("zstd makes a compression context"),
        Decompressor::new().expect("zstd makes a decompression context"),
    ));
}

/// A step's heightmaps, compressed; cloning shares them.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedObservation(Arc<[u8]>);

/// Written as one run of bytes (header and frame), not byte by byte.
impl Serialize for PackedObservation {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_bytes(&self.0)
    }
}

impl<'de> Deserialize<'de> for PackedObservation {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let bytes: Cow<'de, [u8]> = serde_bytes::deserialize(deserializer)?;
        Ok(Self(Arc::from(&*bytes)))
    }
}

/// What the rings hold: a transition whose observation is packed.
pub type StoredTransition = Transition<PackedObservation>;

/// Why packed bytes could not become heightmaps again.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CorruptObservation {
    #[error("its bytes do not match their hash (damaged after they were packed)")]
    Hash,
    #[error("its header is damaged: {0}")]
    Header(String),
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
        let frame = CODEC.with_borrow_mut(|(compressor, _)| compressor.compress(&planes));
        let frame = frame.expect("zstd compresses any bytes into a buffer it sizes itself");
        let mut bytes = Vec::with_capacity(HEADER + frame.len());
        bytes.extend_from_slice(&xxhash_rust::xxh3::xxh3_64(&frame).to_le_bytes());
        bytes.extend_from_slice(&obs.grid.pixel_size().to_le_bytes());
        bytes.extend_from_slice(&frame);
        Self(bytes.into())
    }

    /// The heightmaps, bit for bit as they were packed.
    pub fn unpack(&self) -> Result<Heightmaps, CorruptObservation> {
        let grid = self.grid()?;
        let pixels = grid.len();
        let expected = pixels * PLANE_BYTES_PER_PIXEL;
        // One byte of room: a frame that decodes to more than a grid's planes is refused
        // instead of cut short.
        let planes = CODEC
            .with_borrow_mut(|(_, decompressor)| {
                decompressor.decompress(self.compressed(), expected + 1)
            })
            .map_err(|e| CorruptObservation::Codec(e.to_string()))?;
        if planes.len() != expected {
            return Err(CorruptObservation::Length {
                found: planes.len(),
                expected,
                side: grid.side(),
            });
        }
        let (colour, rest) = planes.split_at(3 * pixels);
        let (height, ids) = rest.split_at(4 * pixels);
        let (r, gb) = colour.split_at(pixels);
        let (g, b) = gb.split_at(pixels);
        let (h01, h23) = height.split_at(2 * pixels);
        let (h0, h1) = h01.split_at(pixels);
        let (h2, h3) = h23.split_at(pixels);
        // Zipped slices of equal length: the loops compile without bounds checks.
        let colour = r.iter().zip(g).zip(b).map(|((&r, &g), &b)| [r, g, b]);
        let height = h0.iter().zip(h1).zip(h2).zip(h3);
        Ok(Heightmaps {
            grid,
            colour: colour.collect(),
            height: height
                .map(|(((&b0, &b1), &b2), &b3)| f32::from_le_bytes([b0, b1, b2, b3]))
                .collect(),
            ids: ids.to_vec(),
        })
    }

    /// Whether the header is whole and the frame is what was packed; the grid it was packed
    /// on.
    pub fn check(&self) -> Result<(), CorruptObservation> {
        self.grid().map(drop)
    }

    fn grid(&self) -> Result<PixelGrid, CorruptObservation> {
        let Some((header, frame)) = self.0.split_at_checked(HEADER) else {
            let why = format!("{} bytes, shorter than the header", self.0.len());
            return Err(CorruptObservation::Header(why));
        };
        let hash = u64::from_le_bytes(header[..8].try_into().expect("8 bytes"));
        if xxhash_rust::xxh3::xxh3_64(frame) != hash {
            return Err(CorruptObservation::Hash);
        }
        let pixel_size = f32::from_le_bytes(header[8..].try_into().expect("4 bytes"));
        PixelGrid::new(pixel_size).map_err(|e| CorruptObservation::Header(e.to_string()))
    }

    /// The compressed frame, as it is stored and written to snapshots.
    pub fn compressed(&self) -> &[u8] {
        &self.0[HEADER..]
    }

    /// Whether `self` and `other` are one stored observation (not merely equal ones).
    pub fn shares(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }

    /// The address of the stored bytes: the same for every holder of one observation.
    pub fn address(&self) -> *const u8 {
        self.0.as_ptr()
    }

    /// The bytes one packed observation takes (header and frame).
    pub fn stored_bytes(&self) -> usize {
        self.0.len()
    }
}

/// `transition` as the rings hold it: its observations packed, shared by nothing yet.
pub fn store(transition: Transition) -> StoredTransition {
    transition.map_obs(|obs| PackedObservation::pack(&obs))
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

    /// `packed` with its frame replaced by `frame` (and a hash that matches it).
    fn with_frame(packed: &PackedObservation, frame: &[u8]) -> PackedObservation {
        let mut bytes = packed.0.to_vec();
        bytes.truncate(HEADER);
        bytes[..8].copy_from_slice(&xxhash_rust::xxh3::xxh3_64(frame).to_le_bytes());
        bytes.extend_from_slice(frame);
        PackedObservation(bytes.into())
    }

    #[test]
    fn damaged_bytes_are_refused_not_decoded() {
        let packed = PackedObservation::pack(&scene());
        let mut bytes = packed.0.to_vec();
        bytes[HEADER + 10] ^= 0x40;
        let flipped = PackedObservation(bytes.into());
        assert_eq!(flipped.unpack(), Err(CorruptObservation::Hash));
        assert!(matches!(
            PackedObservation(vec![1, 2, 3].into()).unpack(),
            Err(CorruptObservation::Header(_))
        ));
        // Frames that match their hash but are not this grid's planes.
        let short = zstd::bulk::compress(&[1, 2, 3], LEVEL).unwrap();
        assert!(matches!(
            with_frame(&packed, &short).unpack(),
            Err(CorruptObservation::Length { found: 3, .. })
        ));
        assert!(matches!(
            with_frame(&packed, &[0; 16]).unpack(),
            Err(CorruptObservation::Codec(_))
        ));
    }
}
