//! The buffer's settings, read from the `[buffer]` table of a run's config.

use serde::{Deserialize, Serialize};

use sim::{ConfigError, above};

use crate::rate_limit::RateLimiter;

/// Capacity, prioritisation and rate limit of the replay buffer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BufferConfig {
    /// Transitions kept per primitive (push and grasp each have a ring of this size); the
    /// oldest is overwritten when a ring is full.
    pub capacity: usize,
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
}

impl Default for BufferConfig {
    fn default() -> Self {
        Self {
            capacity: 4096,
            alpha: 0.6,
            beta_start: 0.4,
            beta_anneal_samples: 100_000,
            priority_epsilon: 1e-3,
            min_size_to_sample: 64,
            samples_per_insert: 8.0,
            error_buffer: 256.0,
            relabel: true,
        }
    }
}

impl BufferConfig {
    /// Checks every field, the rate limiter's rules included.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.capacity == 0 || u32::try_from(self.capacity).is_err() {
            let why = format!("{} is not in 1..=2^32-1", self.capacity);
            return Err(ConfigError::new("capacity", why));
        }
        ConfigError::check_range("alpha", self.alpha, 0.0..)?;
        ConfigError::check_range("beta_start", self.beta_start, 0.0..=1.0)?;
        ConfigError::check_range("priority_epsilon", self.priority_epsilon, above(0.0))?;
        self.rate_limiter().map(drop)
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
