//! Snapshots: the whole buffer (config, both rings with their priorities, counters, the rate
//! limiter, open episodes) in one file, written atomically and checked when read.
//!
//! Layout: 8 bytes of magic, the format version (u32), the payload's length (u64) and its
//! FNV-1a 64 hash (u64), all little-endian, then the payload (postcard). The hash turns a
//! flipped byte into a clear error instead of a plausible but wrong buffer.

use std::fs::{self, File};
use std::hash::Hasher;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use crate::error::{SnapshotError, SnapshotErrorKind};
use crate::store::ReplayBuffer;

const MAGIC: &[u8; 8] = b"PGREPLAY";
/// Bump when the payload's layout changes.
const VERSION: u32 = 1;
const HEADER: usize = 8 + 4 + 8 + 8;

/// Counts and hashes what passes through, so the payload streams to disk without a copy.
struct Hashing<W> {
    inner: W,
    len: u64,
    hash: fnv::FnvHasher,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.len += n as u64;
        self.hash.write(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl ReplayBuffer {
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
            let mut hashing = Hashing {
                inner: file,
                len: 0,
                hash: fnv::FnvHasher::default(),
            };
            postcard::to_io(self, &mut hashing)?;
            let (len, hash) = (hashing.len, hashing.hash.finish());
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

    /// Reads a buffer written by [`save`](Self::save), checking its header, length, hash and
    /// the consistency of what it holds.
    pub fn load(path: &Path) -> Result<Self, SnapshotError> {
        read(path).map_err(|kind| SnapshotError {
            path: path.to_path_buf(),
            kind,
        })
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
    let mut fnv = fnv::FnvHasher::default();
    fnv.write(payload);
    if fnv.finish() != hash {
        return Err(SnapshotErrorKind::Checksum);
    }
    let buffer: ReplayBuffer = postcard::from_bytes(payload)?;
    buffer.check().map_err(SnapshotErrorKind::Invalid)?;
    Ok(buffer)
}
