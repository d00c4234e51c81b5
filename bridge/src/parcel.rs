//! Parcels: what a joined host's bridge publishes up. Steps and episode ends waiting in the
//! host's shared memory go in batches, compressed: heightmaps of blocks on a table are mostly
//! flat, a step at 112 x 112 shrinks about tenfold, and a parcel of several steps pays the
//! link's per-message cost once. A parcel aims at fitting one Zenoh batch (64 KiB) once
//! compressed: a larger message is cut into fragments and rejoined, which halves Zenoh's
//! throughput on a fast link (`bench hosts`), while a message that fits goes as fast as a
//! plain TCP socket. How much raw data fits is learnt from the last parcel's ratio.
//!
//! A parcel is one tag byte, its number in the host's stream (u64, little-endian, from 1),
//! then its body: [`Parcel::Messages`] is a zstd frame of wire-encoded messages, each after
//! its length (u32, little-endian); [`Parcel::Done`] has no body and says the host has sent
//! all it will. The central host acknowledges the newest number it took (flow control: a host
//! has a few parcels in flight at most).

use thiserror::Error;

/// Raw bytes a parcel gathers at most before it is sent.
const PARCEL_RAW_BYTES: usize = 1 << 20;

/// The compressed size a parcel aims at: under Zenoh's batch of 64 KiB, with room for a
/// parcel that compresses less well than the last.
const WIRE_BYTES: usize = 20 << 10;

/// The compression ratio assumed before the first parcel (steps at 112 x 112 shrink 12-50x).
const FIRST_RATIO: usize = 8;

/// zstd's level for parcels: its fastest standard level already shrinks a step about tenfold
/// (higher levels gain a few percent at several times the time).
const LEVEL: i32 = 1;

const MESSAGES: u8 = 0;
const DONE: u8 = 1;

/// The longest a parcel may be once decompressed (a bound against a hostile frame).
const MAX_RAW_BYTES: usize = 256 << 20;

#[derive(Debug, Error)]
pub enum ParcelError {
    #[error("a parcel of {0} bytes, shorter than its header")]
    Short(usize),
    #[error("a parcel of unknown kind {0}")]
    UnknownKind(u8),
    #[error("a parcel that does not decompress: {0}")]
    Compression(#[from] std::io::Error),
    #[error("a parcel cut inside message {index}")]
    Truncated { index: usize },
}

/// A parcel read back.
#[derive(Debug, PartialEq)]
pub enum Parcel {
    /// Wire messages, in the order they were packed.
    Messages(Vec<Vec<u8>>),
    /// The host has stopped and sent everything.
    Done,
}

/// Gathers messages into one parcel.
pub struct Packer {
    raw: Vec<u8>,
    messages: usize,
    /// Raw bytes expected to compress to about [`WIRE_BYTES`].
    raw_target: usize,
}

impl Default for Packer {
    fn default() -> Self {
        Self {
            raw: Vec::new(),
            messages: 0,
            raw_target: FIRST_RATIO * WIRE_BYTES,
        }
    }
}

impl Packer {
    pub fn push(&mut self, message: &[u8]) {
        let len = u32::try_from(message.len()).expect("a wire message is under 4 GiB");
        self.raw.extend_from_slice(&len.to_le_bytes());
        self.raw.extend_from_slice(message);
        self.messages += 1;
    }

    /// Messages gathered.
    pub fn len(&self) -> usize {
        self.messages
    }

    pub fn is_empty(&self) -> bool {
        self.messages == 0
    }

    /// Bytes gathered, before compression.
    pub fn raw_len(&self) -> usize {
        self.raw.len()
    }

    /// Throws away what was gathered.
    pub fn clear(&mut self) {
        self.raw.clear();
        self.messages = 0;
    }

    /// Whether the parcel should go now rather than gather more.
    pub fn full(&self) -> bool {
        self.raw.len() >= self.raw_target
    }

    /// The parcel's bytes, numbered `number`; the packer is empty again.
    pub fn seal(&mut self, number: u64) -> Vec<u8> {
        let mut parcel = header(MESSAGES, number);
        // Writing into a Vec fails only when memory does.
        zstd::stream::copy_encode(self.raw.as_slice(), &mut parcel, LEVEL)
            .expect("compressing into memory");
        let ratio = self.raw.len() as f64 / parcel.len() as f64;
        self.raw_target = ((ratio * WIRE_BYTES as f64) as usize).clamp(1, PARCEL_RAW_BYTES);
        self.clear();
        parcel
    }
}

fn header(kind: u8, number: u64) -> Vec<u8> {
    let mut parcel = vec![kind];
    parcel.extend_from_slice(&number.to_le_bytes());
    parcel
}

/// The parcel, numbered `number`, that says a host is done.
pub fn done(number: u64) -> Vec<u8> {
    header(DONE, number)
}

/// Reads a parcel: its number and what it holds.
pub fn unpack(bytes: &[u8]) -> Result<(u64, Parcel), ParcelError> {
    let (&kind, rest) = bytes.split_first().ok_or(ParcelError::Short(0))?;
    let (number, body) = rest
        .split_first_chunk::<8>()
        .ok_or(ParcelError::Short(bytes.len()))?;
    Ok((u64::from_le_bytes(*number), unpack_body(kind, body)?))
}

fn unpack_body(kind: u8, body: &[u8]) -> Result<Parcel, ParcelError> {
    match kind {
        DONE => Ok(Parcel::Done),
        MESSAGES => {
            let mut raw = Vec::new();
            let mut decoder = zstd::stream::Decoder::new(body)?;
            std::io::copy(
                &mut std::io::Read::take(&mut decoder, MAX_RAW_BYTES as u64),
                &mut raw,
            )?;
            let mut messages = Vec::new();
            let mut rest = raw.as_slice();
            while !rest.is_empty() {
                let truncated = ParcelError::Truncated {
                    index: messages.len(),
                };
                let (len, tail) = rest.split_first_chunk::<4>().ok_or(truncated)?;
                let len = u32::from_le_bytes(*len) as usize;
                if tail.len() < len {
                    return Err(ParcelError::Truncated {
                        index: messages.len(),
                    });
                }
                messages.push(tail[..len].to_vec());
                rest = &tail[len..];
            }
            Ok(Parcel::Messages(messages))
        }
        other => Err(ParcelError::UnknownKind(other)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_come_back_whole_and_in_order() {
        let mut packer = Packer::default();
        let messages: Vec<Vec<u8>> = (0..5u8).map(|i| vec![i; 1000 * usize::from(i)]).collect();
        for m in &messages {
            packer.push(m);
        }
        assert_eq!(packer.len(), 5);
        let parcel = packer.seal(7);
        assert!(packer.is_empty());
        assert!(parcel.len() < 200, "flat bytes compress: {}", parcel.len());
        assert_eq!(unpack(&parcel).unwrap(), (7, Parcel::Messages(messages)));
        assert_eq!(unpack(&done(8)).unwrap(), (8, Parcel::Done));
    }

    #[test]
    fn damaged_parcels_are_errors() {
        let mut packer = Packer::default();
        packer.push(&[7; 100]);
        let parcel = packer.seal(1);
        assert!(matches!(unpack(&[]), Err(ParcelError::Short(0))));
        assert!(matches!(unpack(&[0, 1]), Err(ParcelError::Short(2))));
        assert!(matches!(
            unpack(&done(1)[..]).map(|p| p.1),
            Ok(Parcel::Done)
        ));
        assert!(matches!(unpack(&[9; 9]), Err(ParcelError::UnknownKind(9))));
        assert!(matches!(
            unpack(&parcel[..parcel.len() / 2]),
            Err(ParcelError::Compression(_))
        ));
        // A frame whose content claims a longer message than it holds.
        let mut cut = header(MESSAGES, 1);
        zstd::stream::copy_encode(&[200u8, 0, 0, 0, 1, 2][..], &mut cut, LEVEL).unwrap();
        assert!(matches!(
            unpack(&cut),
            Err(ParcelError::Truncated { index: 0 })
        ));
    }
}
