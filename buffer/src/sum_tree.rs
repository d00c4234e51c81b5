//! A sum tree: a fixed number of non-negative weights with O(log n) update and O(log n)
//! search for the slot where a running prefix sum crosses a value, the core of proportional
//! prioritised sampling.

use serde::{Deserialize, Serialize};

/// Weights over `capacity` slots, stored as a complete binary tree whose inner nodes hold the
/// sums of their children. Serialised as its leaves only; the inner sums are rebuilt on load,
/// so a snapshot can never hold sums that disagree with its leaves.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(into = "Vec<f64>", try_from = "Vec<f64>")]
pub struct SumTree {
    capacity: usize,
    /// Leaves padded to a power of two; node `i` has children `2i` and `2i + 1`, the root is
    /// node 1 and leaf `j` is node `leaves + j`. Padding leaves stay 0.
    leaves: usize,
    nodes: Vec<f64>,
}

impl SumTree {
    /// A tree of `capacity` slots, all of weight 0.
    ///
    /// # Panics
    /// If `capacity` is 0.
    pub fn new(capacity: usize) -> Self {
        assert!(capacity > 0, "a sum tree needs at least one slot");
        let leaves = capacity.next_power_of_two();
        Self {
            capacity,
            leaves,
            nodes: vec![0.0; 2 * leaves],
        }
    }

    /// The number of slots.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The sum of all weights.
    pub fn total(&self) -> f64 {
        self.nodes[1]
    }

    /// The weight of `slot`.
    ///
    /// # Panics
    /// If `slot >= capacity`.
    pub fn get(&self, slot: usize) -> f64 {
        assert!(slot < self.capacity, "slot {slot} out of {}", self.capacity);
        self.nodes[self.leaves + slot]
    }

    /// Sets the weight of `slot` and the sums above it.
    ///
    /// # Panics
    /// If `slot >= capacity` or `weight` is negative or not finite (either would corrupt
    /// every sum above it).
    pub fn set(&mut self, slot: usize, weight: f64) {
        assert!(slot < self.capacity, "slot {slot} out of {}", self.capacity);
        assert!(
            weight.is_finite() && weight >= 0.0,
            "sum tree weight {weight} is not a finite non-negative number"
        );
        let mut node = self.leaves + slot;
        self.nodes[node] = weight;
        // Recompute each parent from its children rather than adding a delta, so rounding
        // errors never accumulate over millions of updates.
        while node > 1 {
            node /= 2;
            self.nodes[node] = self.nodes[2 * node] + self.nodes[2 * node + 1];
        }
    }

    /// The slot where the running sum of weights (in slot order) first exceeds `prefix`:
    /// the smallest `i` with `prefix < w_0 + ... + w_i`. A `prefix` at or beyond the total
    /// (rounding in the caller) gives the last slot of non-zero weight, so the answer always
    /// has a positive weight. Returns `None` when the total is 0.
    pub fn find(&self, prefix: f64) -> Option<usize> {
        if self.total() <= 0.0 {
            return None;
        }
        let mut prefix = prefix.max(0.0);
        let mut node = 1;
        while node < self.leaves {
            let left = self.nodes[2 * node];
            let right = self.nodes[2 * node + 1];
            // Going left when the right subtree is empty keeps the search inside weight:
            // every node visited has a positive sum.
            if prefix < left || right <= 0.0 {
                node *= 2;
            } else {
                prefix -= left;
                node = 2 * node + 1;
            }
        }
        Some(node - self.leaves)
    }
}

impl From<SumTree> for Vec<f64> {
    fn from(tree: SumTree) -> Self {
        tree.nodes[tree.leaves..tree.leaves + tree.capacity].to_vec()
    }
}

impl TryFrom<Vec<f64>> for SumTree {
    type Error = String;

    fn try_from(weights: Vec<f64>) -> Result<Self, Self::Error> {
        if weights.is_empty() {
            return Err("a sum tree needs at least one slot".into());
        }
        if let Some(bad) = weights.iter().find(|w| !(w.is_finite() && **w >= 0.0)) {
            return Err(format!(
                "sum tree weight {bad} is not finite and non-negative"
            ));
        }
        let mut tree = SumTree::new(weights.len());
        tree.nodes[tree.leaves..tree.leaves + weights.len()].copy_from_slice(&weights);
        for node in (1..tree.leaves).rev() {
            tree.nodes[node] = tree.nodes[2 * node] + tree.nodes[2 * node + 1];
        }
        Ok(tree)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The obvious linear implementation the tree must agree with.
    fn naive_find(weights: &[f64], prefix: f64) -> Option<usize> {
        let mut sum = 0.0;
        for (i, w) in weights.iter().enumerate() {
            sum += w;
            if prefix < sum {
                return Some(i);
            }
        }
        weights.iter().rposition(|w| *w > 0.0)
    }

    #[test]
    fn agrees_with_a_naive_implementation_under_random_operations() {
        for (seed, capacity) in [(1u64, 1usize), (2, 2), (3, 5), (4, 64), (5, 100)] {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut tree = SumTree::new(capacity);
            let mut naive = vec![0.0f64; capacity];
            for _ in 0..2_000 {
                let slot = rng.random_range(0..capacity);
                // Zeros are frequent on purpose: they are where a search can go wrong.
                let weight = if rng.random::<f64>() < 0.2 {
                    0.0
                } else {
                    rng.random_range(0.0..10.0)
                };
                tree.set(slot, weight);
                naive[slot] = weight;

                let total: f64 = naive.iter().sum();
                assert!((tree.total() - total).abs() <= 1e-9 * total.max(1.0));
                assert_eq!(tree.get(slot), weight);
                for _ in 0..4 {
                    let prefix = rng.random::<f64>() * total;
                    let found = tree.find(prefix);
                    let expected = naive_find(&naive, prefix);
                    // Rounding may differ between the two sums right at a boundary; then
                    // both answers must be adjacent non-zero slots around it.
                    if found != expected {
                        let (f, e) = (found.unwrap(), expected.unwrap());
                        let boundary: f64 = naive[..f.max(e)].iter().sum();
                        assert!(
                            (boundary - prefix).abs() < 1e-9,
                            "{found:?} vs {expected:?}"
                        );
                    }
                    if let Some(slot) = found {
                        assert!(naive[slot] > 0.0, "found a slot of zero weight");
                    }
                }
            }
        }
    }

    #[test]
    fn search_at_or_past_the_total_lands_on_the_last_weighted_slot() {
        let mut tree = SumTree::new(6);
        assert_eq!(tree.find(0.0), None);
        tree.set(1, 2.0);
        tree.set(3, 1.0);
        assert_eq!(tree.find(0.0), Some(1));
        assert_eq!(tree.find(1.999), Some(1));
        assert_eq!(tree.find(2.0), Some(3));
        assert_eq!(tree.find(3.0), Some(3));
        assert_eq!(tree.find(1e9), Some(3));
        assert_eq!(tree.find(-1.0), Some(1));
    }

    #[test]
    fn leaves_round_trip_and_bad_weights_are_refused() {
        let mut tree = SumTree::new(5);
        for (slot, w) in [(0, 1.5), (2, 0.25), (4, 3.0)] {
            tree.set(slot, w);
        }
        let leaves: Vec<f64> = tree.clone().into();
        assert_eq!(leaves, vec![1.5, 0.0, 0.25, 0.0, 3.0]);
        assert_eq!(SumTree::try_from(leaves).unwrap(), tree);
        assert!(SumTree::try_from(vec![]).is_err());
        assert!(SumTree::try_from(vec![1.0, f64::NAN]).is_err());
        assert!(SumTree::try_from(vec![-1.0]).is_err());
    }
}
