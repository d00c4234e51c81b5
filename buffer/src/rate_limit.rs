//! A samples-per-insert rate limiter with the semantics of Reverb's `SampleToInsertRatio`, so
//! the learner neither starves (sampling the same few steps over and over) nor falls behind
//! the actors (their steps overwritten before they are learnt from).
//!
//! Reverb's rules, kept exactly:
//! - `offset = samples_per_insert x min_size_to_sample`, `min_diff = offset - error_buffer`,
//!   `max_diff = offset + error_buffer`; `diff = inserts x samples_per_insert - samples`.
//! - Stage 1: until `inserts - deletes` reaches `min_size_to_sample`, inserts are always
//!   allowed (`inserts + n - deletes <= min_size_to_sample`) and sampling never is.
//! - Stage 2: `n` samples are allowed while `diff - n >= min_diff`, `n` inserts while
//!   `(inserts + n) x samples_per_insert - samples <= max_diff`.
//! - Built only when `samples_per_insert > 0`, `min_size_to_sample >= 1` and
//!   `error_buffer >= max(1, samples_per_insert)`: a smaller buffer could block both sides.
//!
//! The limiter only answers and counts; the wiring decides what to do with a "no" (pause
//! reading its transport, or tell the learner to wait).

use serde::{Deserialize, Serialize};
use sim::{ConfigError, above};

/// Counts of inserts, samples and deletes, and the window the samples-per-insert ratio must
/// stay in.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RateLimiter {
    samples_per_insert: f64,
    min_size_to_sample: u64,
    min_diff: f64,
    max_diff: f64,
    inserts: u64,
    samples: u64,
    deletes: u64,
}

impl RateLimiter {
    /// Reverb's `SampleToInsertRatio(samples_per_insert, min_size_to_sample, error_buffer)`.
    pub fn sample_to_insert_ratio(
        samples_per_insert: f64,
        min_size_to_sample: u64,
        error_buffer: f64,
    ) -> Result<Self, ConfigError> {
        ConfigError::check_range("samples_per_insert", samples_per_insert, above(0.0))?;
        if min_size_to_sample == 0 {
            return Err(ConfigError::new("min_size_to_sample", "must be at least 1"));
        }
        if !(error_buffer.is_finite() && error_buffer >= samples_per_insert.max(1.0)) {
            return Err(ConfigError::new(
                "error_buffer",
                format!(
                    "{error_buffer} is below max(1, samples_per_insert) = {}, which could \
                     block both inserts and samples",
                    samples_per_insert.max(1.0)
                ),
            ));
        }
        let offset = samples_per_insert * min_size_to_sample as f64;
        Ok(Self {
            samples_per_insert,
            min_size_to_sample,
            min_diff: offset - error_buffer,
            max_diff: offset + error_buffer,
            inserts: 0,
            samples: 0,
            deletes: 0,
        })
    }

    fn size(&self) -> u64 {
        self.inserts.saturating_sub(self.deletes)
    }

    fn diff(&self) -> f64 {
        self.inserts as f64 * self.samples_per_insert - self.samples as f64
    }

    /// Whether `n` more items may be inserted now.
    pub fn can_insert(&self, n: u64) -> bool {
        if self.size() + n <= self.min_size_to_sample {
            return true;
        }
        (self.inserts + n) as f64 * self.samples_per_insert - self.samples as f64 <= self.max_diff
    }

    /// Whether `n` more items may be sampled now.
    pub fn can_sample(&self, n: u64) -> bool {
        self.size() >= self.min_size_to_sample && self.diff() - n as f64 >= self.min_diff
    }

    /// Counts `n` inserted items.
    pub fn on_insert(&mut self, n: u64) {
        self.inserts += n;
    }

    /// Counts `n` sampled items.
    pub fn on_sample(&mut self, n: u64) {
        self.samples += n;
    }

    /// Counts `n` items removed (overwritten in a full ring): they no longer count towards
    /// the minimum size.
    pub fn on_delete(&mut self, n: u64) {
        self.deletes += n;
    }

    /// Items inserted so far.
    pub fn inserts(&self) -> u64 {
        self.inserts
    }

    /// Items sampled so far.
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Items deleted so far.
    pub fn deletes(&self) -> u64 {
        self.deletes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_settings_are_refused_as_reverb_refuses_them() {
        assert!(RateLimiter::sample_to_insert_ratio(0.0, 1, 1.0).is_err());
        assert!(RateLimiter::sample_to_insert_ratio(-1.0, 1, 1.0).is_err());
        assert!(RateLimiter::sample_to_insert_ratio(1.0, 0, 1.0).is_err());
        assert!(RateLimiter::sample_to_insert_ratio(4.0, 1, 3.9).is_err());
        assert!(RateLimiter::sample_to_insert_ratio(0.5, 1, 0.9).is_err());
        assert!(RateLimiter::sample_to_insert_ratio(4.0, 1, 4.0).is_ok());
        assert!(RateLimiter::sample_to_insert_ratio(0.5, 1, 1.0).is_ok());
    }

    #[test]
    fn stage_one_inserts_freely_and_never_samples() {
        // spi 2, min size 3, error buffer 2: offset 6, window [4, 8].
        let mut l = RateLimiter::sample_to_insert_ratio(2.0, 3, 2.0).unwrap();
        assert!(l.can_insert(3), "up to min_size_to_sample inserts are free");
        assert!(!l.can_sample(1));
        l.on_insert(2);
        assert!(!l.can_sample(1), "2 of 3 inserted");
        l.on_insert(1);
        // inserts 3, samples 0: diff 6; sampling n needs 6 - n >= 4.
        assert!(l.can_sample(1));
        assert!(l.can_sample(2));
        assert!(!l.can_sample(3));
        // Inserting 1 more: 4 x 2 - 0 = 8 <= 8; 2 more: 10 > 8.
        assert!(l.can_insert(1));
        assert!(!l.can_insert(2));
    }

    #[test]
    fn stage_two_holds_the_ratio_within_the_error_buffer() {
        let mut l = RateLimiter::sample_to_insert_ratio(2.0, 3, 2.0).unwrap();
        l.on_insert(4); // diff 8: at the insert edge.
        assert!(!l.can_insert(1));
        assert!(l.can_sample(4), "8 - 4 = 4 >= 4");
        assert!(!l.can_sample(5));
        l.on_sample(4); // diff 4: sampling must wait, inserting may go on.
        assert!(!l.can_sample(1));
        assert!(l.can_insert(1));
        assert!(!l.can_insert(3), "(4 + 3) x 2 - 4 = 10 > 8");
        l.on_insert(1);
        assert!(l.can_sample(2));
        assert_eq!((l.inserts(), l.samples(), l.deletes()), (5, 4, 0));
    }

    #[test]
    fn deletes_bring_the_size_back_below_the_minimum() {
        let mut l = RateLimiter::sample_to_insert_ratio(1.0, 3, 1.0).unwrap();
        l.on_insert(3);
        assert!(l.can_sample(1));
        l.on_delete(1);
        assert!(!l.can_sample(1), "2 items left of a minimum of 3");
        // Far ahead of the ratio ((10 + 1) x 1 - 0 > 4), but with 2 items left inserts are
        // free again.
        l.on_insert(7);
        l.on_delete(7);
        assert!(l.can_insert(1));
        assert!(!l.can_insert(2));
    }
}
