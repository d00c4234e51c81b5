//! The buffer's settings, read from the `[buffer]` table of a run's config.

use std::fmt;

use serde::de::{self, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use experience::{PackedObservation, StoredTransition};
use sim::{Camera, ConfigError, SimConfig, SimError, Tabletop, above};

use crate::rate_limit::RateLimiter;

/// How much the buffer keeps: transitions per primitive's ring, or a memory budget for both
/// rings together, which becomes transitions once the run's bytes per stored step are known
/// ([`BufferConfig::resolve`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Capacity {
    Steps(usize),
    Bytes(u64),
}

impl fmt::Display for Capacity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Capacity::Steps(n) => write!(f, "{n}"),
            Capacity::Bytes(b) => write!(f, "{}", bytesize::ByteSize(*b).display().iec()),
        }
    }
}

/// Written as a config says it, a number (transitions) or a string with a unit (bytes);
/// as a string in formats that do not describe themselves (the snapshot's), which can then
/// read it back.
impl Serialize for Capacity {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            Capacity::Steps(n) if serializer.is_human_readable() => {
                serializer.serialize_u64(*n as u64)
            }
            Capacity::Steps(n) => serializer.serialize_str(&n.to_string()),
            Capacity::Bytes(b) => serializer.serialize_str(&format!("{b} B")),
        }
    }
}

impl<'de> Deserialize<'de> for Capacity {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct CapacityVisitor;
        impl Visitor<'_> for CapacityVisitor {
            type Value = Capacity;

            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a number of transitions per ring, or a size such as \"8 GiB\"")
            }

            fn visit_u64<E: de::Error>(self, n: u64) -> Result<Capacity, E> {
                usize::try_from(n)
                    .map(Capacity::Steps)
                    .map_err(|_| E::custom(format!("{n} transitions do not fit this machine")))
            }

            fn visit_i64<E: de::Error>(self, n: i64) -> Result<Capacity, E> {
                let n = u64::try_from(n).map_err(|_| E::custom(format!("{n} is negative")))?;
                self.visit_u64(n)
            }

            fn visit_str<E: de::Error>(self, text: &str) -> Result<Capacity, E> {
                if let Ok(n) = text.trim().parse::<u64>() {
                    return self.visit_u64(n);
                }
                let size: bytesize::ByteSize = text.parse().map_err(|why| {
                    E::custom(format!(
                        "{text:?} is neither a number of transitions nor a size such as \"8 GiB\" ({why})"
                    ))
                })?;
                Ok(Capacity::Bytes(size.as_u64()))
            }
        }
        if deserializer.is_human_readable() {
            deserializer.deserialize_any(CapacityVisitor)
        } else {
            deserializer.deserialize_str(CapacityVisitor)
        }
    }
}

/// Capacity, prioritisation and rate limit of the replay buffer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BufferConfig {
    /// Transitions kept per primitive (push and grasp each have a ring of this size; the
    /// oldest is overwritten when a ring is full), or a memory budget for both rings
    /// (`"8 GiB"`), resolved to transitions at start.
    pub capacity: Capacity,
    /// Prioritisation exponent: P(i) = p_i^alpha / sum_k p_k^alpha (0 is uniform).
    pub alpha: f64,
    /// Importance-sampling exponent at the start; it rises linearly to 1.
    pub beta_start: f64,
    /// Sampled items (summed over both primitives) over which beta reaches 1.
    pub beta_anneal_samples: u64,
    /// The smallest priority kept, so that no transition's probability falls to 0.
    pub priority_epsilon: f64,
    /// Inserts before the first sample may be drawn (Reverb's `min_size_to_sample`).
    pub min_size_to_sample: u64,
    /// Sampled items per inserted item the rate limiter holds the run to.
    pub samples_per_insert: f64,
    /// How far, in sampled items, the run may stray from that ratio before the side ahead
    /// is held back (Reverb's `error_buffer`).
    pub error_buffer: f64,
    /// Goal relabelling: a grasp of another object than the goal is stored again for that
    /// object, with the episode's pushes. False for the ablation without it.
    pub relabel: bool,
    /// Seconds between the snapshots the buffer role writes in the background while it
    /// serves (besides those on request and at the end); 0 for none.
    pub snapshot_every_s: f64,
    /// The share of each batch drawn from transitions with a positive reward (a grasp that
    /// took its goal, a rewarded push), the rest from the others, each part by priority
    /// within its kind; all from one kind while the other has none. The authors' code
    /// replays, after each update, a transition whose reward was the opposite of the
    /// newest one's: 0.5 is that balance. Unset (the paper, Ape-X): one draw by priority
    /// over all.
    pub positive_share: Option<f64>,
}

impl Default for BufferConfig {
    fn default() -> Self {
        Self {
            capacity: Capacity::Steps(4096),
            alpha: 0.6,
            beta_start: 0.4,
            beta_anneal_samples: 100_000,
            priority_epsilon: 1e-3,
            min_size_to_sample: 64,
            samples_per_insert: 8.0,
            error_buffer: 256.0,
            relabel: true,
            snapshot_every_s: 60.0,
            positive_share: None,
        }
    }
}

impl BufferConfig {
    /// Checks every field, the rate limiter's rules included.
    pub fn validate(&self) -> Result<(), ConfigError> {
        match self.capacity {
            Capacity::Steps(n) if n == 0 || u32::try_from(n).is_err() => {
                let why = format!("{n} is not in 1..=2^32-1");
                return Err(ConfigError::new("capacity", why));
            }
            Capacity::Bytes(0) => return Err(ConfigError::new("capacity", "0 bytes")),
            _ => {}
        }
        ConfigError::check_range("alpha", self.alpha, 0.0..)?;
        ConfigError::check_range("beta_start", self.beta_start, 0.0..=1.0)?;
        ConfigError::check_range("priority_epsilon", self.priority_epsilon, above(0.0))?;
        ConfigError::check_range("snapshot_every_s", self.snapshot_every_s, 0.0..)?;
        if let Some(share) = self.positive_share {
            ConfigError::check_range("positive_share", share, 0.0..=1.0)?;
        }
        self.rate_limiter().map(drop)
    }

    /// Transitions per ring; an error while the capacity is a budget in bytes not yet
    /// [`resolve`](Self::resolve)d.
    pub fn slots(&self) -> Result<usize, ConfigError> {
        match self.capacity {
            Capacity::Steps(n) => Ok(n),
            Capacity::Bytes(_) => Err(ConfigError::new(
                "capacity",
                format!("{} must be resolved to transitions first", self.capacity),
            )),
        }
    }

    /// Turns a budget in bytes into transitions per ring, for steps that take
    /// `bytes_per_step` each stored (two rings share the budget); a capacity in transitions
    /// stays as it is.
    pub fn resolve(&mut self, bytes_per_step: usize) {
        if let Capacity::Bytes(budget) = self.capacity {
            let per_ring = budget / (2 * bytes_per_step.max(1) as u64);
            self.capacity = Capacity::Steps(usize::try_from(per_ring.max(1)).unwrap_or(usize::MAX));
        }
    }

    /// The limiter this config asks for.
    pub fn rate_limiter(&self) -> Result<RateLimiter, ConfigError> {
        RateLimiter::sample_to_insert_ratio(
            self.samples_per_insert,
            self.min_size_to_sample,
            self.error_buffer,
        )
    }
}

/// About the bytes one stored step takes: a settled scene of `objects` blocks at the
/// config's resolution, packed, and a slot's bookkeeping (the transition, its generation,
/// priority and share of the sum tree, the shared allocation's counts).
pub fn bytes_per_step(config: &SimConfig, objects: usize) -> Result<usize, SimError> {
    const SLOT_BYTES: usize = std::mem::size_of::<StoredTransition>() + 8 + 8 + 10 + 16;
    let (tabletop, _) = Tabletop::random(config, objects, 0)?;
    let obs = Camera::new(tabletop.grid()).render(&tabletop);
    Ok(PackedObservation::pack(&obs).stored_bytes() + SLOT_BYTES)
}
