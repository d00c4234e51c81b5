//! The bench's messages: their contents, the header that numbers them, the checksum a
//! receiver reads them with, and the clock the latency is read on.

use std::time::{SystemTime, UNIX_EPOCH};

pub(super) fn nanos_now() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// The message publisher `index` sends, before its first 16 bytes get its number (and, for
/// the latency, the time).
pub(super) fn message_of(index: usize, size: usize) -> Vec<u8> {
    (0..size).map(|i| (i * 131 + index) as u8).collect()
}

/// Reads every byte after the first 16 (what a receiver that uses the message does): the
/// wrapping sum of its 8-byte words.
pub(super) fn checksum(bytes: &[u8]) -> u64 {
    bytes[16..]
        .chunks_exact(8)
        .map(|w| u64::from_le_bytes(w.try_into().expect("8 bytes")))
        .fold(0, u64::wrapping_add)
}

/// A message's publisher index and number (its first 8 bytes).
pub(super) fn header(bytes: &[u8]) -> (usize, u64) {
    let word = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes"));
    ((word >> 48) as usize, word & ((1 << 48) - 1))
}
