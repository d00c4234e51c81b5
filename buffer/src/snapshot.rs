//! Snapshots: the whole buffer (config, both rings with their priorities, counters, the rate
//! limiter, open episodes) in one file, written atomically and checked when read.
//!
//! Layout: 8 bytes of magic, the format version (u32), the payload's length (u64) and its
//! xxh3 hash (u64), all little-endian, then the payload (postcard). The rings' sum trees are
//! not written: they are their priorities raised to alpha, rebuilt when read. A ring writes
//! each packed observation once, as it lies in memory (compressed, with its own hash), and its
//! items name theirs (and their successors') by index, so relabelled copies share it again
//! when read; a push's successor held in the other ring is written with both rings. The hashes turn
//! a flipped byte into a clear error instead of a plausible but wrong buffer: the
//! observation's own names the damaged record, the payload's the rest.

use std::collections::HashMap;
use std::fs::{self, File};
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use experience::Transition;
use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use xxhash_rust::xxh3::Xxh3;

use crate::chunks::SharedChunks;
use crate::error::{SnapshotError, SnapshotErrorKind};
use crate::ring::Ring;
use crate::store::{ReplayBuffer, ReplayCopy};
use experience::PackedObservation;

const MAGIC: &[u8; 8] = b"PGREPLAY";
/// Bump when the payload's layout changes.
const VERSION: u32 = 5;
const HEADER: usize = 8 + 4 + 8 + 8;

/// Counts and hashes what passes through, so the payload streams to disk without a copy.
struct Hashing<W> {
    inner: W,
    len: u64,
    hash: Xxh3,
    /// The first write that failed: postcard reports any as "the serialize buffer is
    /// full", which would hide the cause (a full disk).
    failed: Option<std::io::Error>,
}

impl<W: Write> Hashing<W> {
    fn new(inner: W) -> Self {
        Self {
            inner,
            len: 0,
            hash: Xxh3::new(),
            failed: None,
        }
    }

    /// Streams `value` through, encoded; returns the payload's length and hash. A failed
    /// write is the error, as the writer gave it.
    fn encode(&mut self, value: &impl Serialize) -> Result<(u64, u64), SnapshotErrorKind> {
        let encoded = postcard::to_io(value, &mut *self).map(drop);
        if let Some(e) = self.failed.take() {
            return Err(e.into());
        }
        encoded?;
        Ok((self.len, self.hash.digest()))
    }
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf).inspect_err(|e| {
            self.failed
                .get_or_insert_with(|| std::io::Error::new(e.kind(), e.to_string()));
        })?;
        self.len += n as u64;
        self.hash.update(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl ReplayBuffer {
    /// Writes the buffer to `path` (see [`ReplayCopy::save`]).
    pub fn save(&self, path: &Path) -> Result<(), SnapshotError> {
        self.copy_to_save().save(path)
    }

    /// Reads a buffer written by [`save`](Self::save), checking its header, length, hash and
    /// the consistency of what it holds.
    pub fn load(path: &Path) -> Result<Self, SnapshotError> {
        read(path).map_err(|kind| SnapshotError {
            path: path.to_path_buf(),
            kind,
        })
    }
}

impl ReplayCopy {
    /// Writes the buffer to `path`: to `<path>.tmp` first, synced, then renamed over `path`,
    /// so a crash mid-write leaves the previous snapshot intact.
    pub fn save(&self, path: &Path) -> Result<(), SnapshotError> {
        let fail = |kind: SnapshotErrorKind| SnapshotError {
            path: path.to_path_buf(),
            kind,
        };
        let tmp = tmp_path(path);
        let write = || -> Result<(), SnapshotErrorKind> {
            let mut file = BufWriter::new(File::create(&tmp)?);
            file.write_all(&[0; HEADER])?;
            let mut hashing = Hashing::new(file);
            let (len, hash) = hashing.encode(&self.0)?;
            let mut file = hashing.inner.into_inner().map_err(|e| e.into_error())?;
            file.seek(SeekFrom::Start(0))?;
            file.write_all(&header(len, hash))?;
            file.sync_all()?;
            Ok(())
        };
        if let Err(kind) = write() {
            // The temporary file is incomplete; the snapshot at `path` is untouched.
            let _ = fs::remove_file(&tmp);
            return Err(fail(kind));
        }
        fs::rename(&tmp, path).map_err(|e| fail(e.into()))
    }
}

fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".tmp");
    PathBuf::from(name)
}

fn header(len: u64, hash: u64) -> [u8; HEADER] {
    let mut h = [0; HEADER];
    h[..8].copy_from_slice(MAGIC);
    h[8..12].copy_from_slice(&VERSION.to_le_bytes());
    h[12..20].copy_from_slice(&len.to_le_bytes());
    h[20..28].copy_from_slice(&hash.to_le_bytes());
    h
}

fn read(path: &Path) -> Result<ReplayBuffer, SnapshotErrorKind> {
    let bytes = fs::read(path)?;
    let Some((head, payload)) = bytes.split_at_checked(HEADER) else {
        return Err(if bytes.starts_with(MAGIC) || MAGIC.starts_with(&bytes) {
            SnapshotErrorKind::Truncated {
                found: bytes.len() as u64,
                expected: HEADER as u64,
            }
        } else {
            SnapshotErrorKind::BadMagic
        });
    };
    if &head[..8] != MAGIC {
        return Err(SnapshotErrorKind::BadMagic);
    }
    let field = |range: std::ops::Range<usize>| -> u64 {
        let mut b = [0; 8];
        b[..range.len()].copy_from_slice(&head[range]);
        u64::from_le_bytes(b)
    };
    let version = field(8..12) as u32;
    if version != VERSION {
        return Err(SnapshotErrorKind::Version {
            found: version,
            expected: VERSION,
        });
    }
    let (len, hash) = (field(12..20), field(20..28));
    if payload.len() as u64 != len {
        return Err(SnapshotErrorKind::Truncated {
            found: bytes.len() as u64,
            expected: HEADER as u64 + len,
        });
    }
    let intact = || xxhash_rust::xxh3::xxh3_64(payload) == hash;
    // Decoded before the payload's hash is checked, so that a damaged observation is named
    // by its own hash; a payload that does not decode is reported as damaged when it is.
    let mut buffer: ReplayBuffer = match postcard::from_bytes(payload) {
        Ok(buffer) => buffer,
        Err(_) if !intact() => return Err(SnapshotErrorKind::Checksum),
        Err(e) => return Err(e.into()),
    };
    buffer
        .replay()
        .check_observations()
        .map_err(SnapshotErrorKind::Invalid)?;
    if !intact() {
        return Err(SnapshotErrorKind::Checksum);
    }
    buffer
        .check_and_index()
        .map_err(SnapshotErrorKind::Invalid)?;
    Ok(buffer)
}

/// A ring as a snapshot writes it.
#[derive(Serialize)]
struct RingOut<'a> {
    observations: Vec<PackedObservation>,
    /// Each item with the indices of its observations.
    items: Vec<Transition<u32>>,
    generations: &'a SharedChunks<u64>,
    priorities: &'a SharedChunks<f64>,
    capacity: usize,
    inserted: u64,
    max_priority: f64,
}

/// A ring as a snapshot reads it.
#[derive(Deserialize)]
struct RingIn {
    observations: Vec<PackedObservation>,
    items: Vec<Transition<u32>>,
    generations: Vec<u64>,
    priorities: Vec<f64>,
    capacity: usize,
    inserted: u64,
    max_priority: f64,
}

impl Serialize for Ring {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut index = HashMap::new();
        let mut observations = Vec::new();
        let items = self
            .items
            .iter()
            .map(|item| {
                item.clone().map_obs(|obs| {
                    *index.entry(obs.address()).or_insert_with(|| {
                        observations.push(obs);
                        observations.len() as u32 - 1
                    })
                })
            })
            .collect();
        RingOut {
            observations,
            items,
            generations: &self.generations,
            priorities: &self.priorities,
            capacity: self.capacity,
            inserted: self.inserted,
            max_priority: self.max_priority,
        }
        .serialize(serializer)
    }
}

impl<'de> Deserialize<'de> for Ring {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let ring = RingIn::deserialize(deserializer)?;
        let observations = ring.observations;
        let items = ring
            .items
            .into_iter()
            .map(|item| {
                item.try_map_obs(|i| {
                    observations.get(i as usize).cloned().ok_or_else(|| {
                        D::Error::custom(format!(
                            "an item names observation {i} of {}",
                            observations.len()
                        ))
                    })
                })
            })
            .collect::<Result<_, D::Error>>()?;
        Ok(Ring {
            items,
            generations: ring.generations.into_iter().collect(),
            priorities: ring.priorities.into_iter().collect(),
            capacity: ring.capacity,
            inserted: ring.inserted,
            max_priority: ring.max_priority,
        })
    }
}

#[cfg(test)]
mod tests {
    use std::io;

    use super::*;

    /// A disk that fills after `room` bytes.
    struct Filling {
        room: usize,
    }

    impl Write for Filling {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            if self.room == 0 {
                return Err(io::Error::from_raw_os_error(ENOSPC));
            }
            let n = buf.len().min(self.room);
            self.room -= n;
            Ok(n)
        }

        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    /// Linux's "No space left on device".
    const ENOSPC: i32 = 28;

    #[test]
    fn a_full_disk_is_the_error_not_the_encoders_complaint() {
        let payload = vec![7u8; 10_000];
        let err = Hashing::new(Filling { room: 100 })
            .encode(&payload)
            .unwrap_err();
        assert!(err.to_string().contains("No space left on device"), "{err}");
        let (len, _) = Hashing::new(Filling { room: 20_000 })
            .encode(&payload)
            .unwrap();
        assert_eq!(len, 10_002, "the length's varint and the bytes");
    }
}
