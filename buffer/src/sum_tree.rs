//! A sum tree: a fixed number of non-negative weights with O(log n) update and O(log n)
//! search for the slot where a running prefix sum crosses a value, the core of proportional
//! prioritised sampling.
//!
//! Its tests take it past 400 lines; the code itself is under 400.

use serde::{Deserialize, Serialize};

/// Children per inner node: eight `f64`s fill one 64-byte cache line.
const FANOUT: usize = 8;

/// Eight weights, or eight subtree sums, aligned to a cache line so that one step of a search
/// or an update touches one line.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(64))]
struct Group([f64; FANOUT]);

impl Group {
    /// The sum in slot order. Every sum of the tree is computed this one way, so sums
    /// rebuilt from the weights are bit for bit those kept by updates. (Adding pairwise
    /// compiles to wide loads, which stall on the store of the weight just set.)
    fn sum(&self) -> f64 {
        self.0.iter().fold(0.0, |sum, w| sum + w)
    }

    /// The child a search with `prefix` still to cover goes to, and `prefix` less the weight
    /// before that child: the first child where the running sum exceeds `prefix`, or, for a
    /// `prefix` at or past the group's sum, the last child of positive weight. Either has a
    /// positive weight when any child has, and `prefix` stays at or above 0. Computed
    /// without a branch: the answer is unpredictable, and a missed branch would throw away
    /// the loads of the searches running beside this one (`SumTree::find_many`).
    #[inline(always)]
    fn choose(&self, prefix: &mut f64) -> usize {
        let mut before = [0.0f64; FANOUT + 1];
        let mut running = 0.0;
        let mut covered = 0;
        let mut positive = 0u32;
        for (j, &w) in self.0.iter().enumerate() {
            running += w;
            before[j + 1] = running;
            covered += usize::from(running <= *prefix);
            positive |= u32::from(w > 0.0) << j;
        }
        let last_positive = (positive | 1).ilog2() as usize;
        let child = if covered == FANOUT {
            last_positive
        } else {
            covered
        };
        *prefix -= before[child];
        child
    }
}

/// Weights over `capacity` slots in an eight-way tree whose inner entries hold the sums of
/// their children. Serialised as its weights only; the sums are rebuilt on load, so a
/// snapshot can never hold sums that disagree with its weights.
///
/// Eight children to a cache line make a search or an update touch a line per level of
/// eight, not per level of two: a 2^21-slot tree has 7 levels, not 21, and its upper levels
/// (the few that are not the weights themselves) take an eighth of the weights' memory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(into = "Vec<f64>", try_from = "Vec<f64>")]
pub struct SumTree {
    capacity: usize,
    /// `levels[0]` holds the weights, slot `i` at `[i / 8].0[i % 8]`. Entry `g` of level
    /// `k + 1` is the sum of group `g` of level `k`. The last level is a single group.
    /// Padding entries stay 0.
    levels: Vec<Vec<Group>>,
    /// The sum of the last level's group.
    total: f64,
}

impl SumTree {
    /// A tree of `capacity` slots, all of weight 0.
    ///
    /// # Panics
    /// If `capacity` is 0.
    pub fn new(capacity: usize) -> Self {
        assert!(capacity > 0, "a sum tree needs at least one slot");
        let mut levels = Vec::new();
        let mut entries = capacity;
        loop {
            let groups = entries.div_ceil(FANOUT);
            levels.push(vec![Group::default(); groups]);
            if groups == 1 {
                break;
            }
            entries = groups;
        }
        Self {
            capacity,
            levels,
            total: 0.0,
        }
    }

    /// The number of slots.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The sum of all weights.
    pub fn total(&self) -> f64 {
        self.total
    }

    /// The weight of `slot`.
    ///
    /// # Panics
    /// If `slot >= capacity`.
    pub fn get(&self, slot: usize) -> f64 {
        assert!(slot < self.capacity, "slot {slot} out of {}", self.capacity);
        self.levels[0][slot / FANOUT].0[slot % FANOUT]
    }

    /// Sets the weight of `slot` and the sums above it.
    ///
    /// # Panics
    /// If `slot >= capacity` or `weight` is negative or not finite (either would corrupt
    /// every sum above it).
    pub fn set(&mut self, slot: usize, weight: f64) {
        self.set_many(slot, &[weight]);
    }

    /// Sets the weights of the consecutive slots from `start`, then the sums above them a
    /// level at a time, each group touched once: a batch of inserts costs about one pass
    /// over its slots, not a walk up the tree for each.
    ///
    /// # Panics
    /// If a slot is past the capacity or a weight is negative or not finite.
    pub fn set_many(&mut self, start: usize, weights: &[f64]) {
        if weights.is_empty() {
            return;
        }
        let last = start + weights.len() - 1;
        assert!(last < self.capacity, "slot {last} out of {}", self.capacity);
        for (slot, &weight) in (start..).zip(weights) {
            assert!(
                weight.is_finite() && weight >= 0.0,
                "sum tree weight {weight} is not a finite non-negative number"
            );
            self.levels[0][slot / FANOUT].0[slot % FANOUT] = weight;
        }
        self.resum(start, last);
    }

    /// Recomputes the sums above the weights of slots `first..=last` from their children
    /// (never by adding a delta, so rounding errors cannot accumulate over millions of
    /// updates), and the total.
    fn resum(&mut self, first: usize, last: usize) {
        let (mut lo, mut hi) = (first / FANOUT, last / FANOUT);
        for k in 1..self.levels.len() {
            let (below, above) = self.levels.split_at_mut(k);
            for g in lo..=hi {
                above[0][g / FANOUT].0[g % FANOUT] = below[k - 1][g].sum();
            }
            (lo, hi) = (lo / FANOUT, hi / FANOUT);
        }
        self.total = self.levels.last().expect("a tree has a level")[0].sum();
    }

    /// The slot where the running sum of weights (in slot order) first exceeds `prefix`:
    /// the smallest `i` with `prefix < w_0 + ... + w_i`. A `prefix` at or beyond the total
    /// (rounding in the caller) gives the last slot of non-zero weight, so the answer always
    /// has a positive weight. Returns `None` when the total is 0.
    pub fn find(&self, prefix: f64) -> Option<usize> {
        if self.total <= 0.0 {
            return None;
        }
        let mut prefix = prefix.max(0.0);
        let mut entry = 0;
        for level in self.levels.iter().rev() {
            entry = entry * FANOUT + level[entry].choose(&mut prefix);
        }
        Some(entry)
    }

    /// [`find`](Self::find) for many prefixes at once: `slots[i]` gets the slot of
    /// `prefixes[i]`, the very slot `find` gives. Returns false, leaving `slots` as it was,
    /// when the total is 0.
    ///
    /// The searches go down the tree a level at a time side by side. A large replay's tree
    /// is bigger than the inner caches, so the lower levels are waits on memory; this way the
    /// waits of different searches overlap instead of queueing behind each other.
    ///
    /// # Panics
    /// If the two slices differ in length.
    pub fn find_many(&self, prefixes: &[f64], slots: &mut [usize]) -> bool {
        assert_eq!(prefixes.len(), slots.len(), "one slot per prefix");
        if self.total <= 0.0 {
            return false;
        }
        /// Searches in flight at once: enough to cover the memory latency, few enough that
        /// their state stays in L1.
        const LANES: usize = 32;
        for (prefixes, slots) in prefixes.chunks(LANES).zip(slots.chunks_mut(LANES)) {
            let mut rest = [0.0f64; LANES];
            let rest = &mut rest[..prefixes.len()];
            for (r, p) in rest.iter_mut().zip(prefixes) {
                *r = p.max(0.0);
            }
            slots.fill(0);
            let mut groups = [Group::default(); LANES];
            for level in self.levels.iter().rev() {
                // Gather first, choose after: the gathering loop is short enough for every
                // lane's load to be in flight at once.
                for (group, entry) in groups.iter_mut().zip(slots.iter()) {
                    *group = level[*entry];
                }
                for ((entry, prefix), group) in slots.iter_mut().zip(rest.iter_mut()).zip(&groups) {
                    *entry = *entry * FANOUT + group.choose(prefix);
                }
            }
        }
        true
    }
}

impl From<SumTree> for Vec<f64> {
    fn from(tree: SumTree) -> Self {
        let weights = tree.levels[0].iter().flat_map(|group| group.0);
        weights.take(tree.capacity).collect()
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
        tree.set_many(0, &weights);
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
        let cases = [
            (1u64, 1usize),
            (2, 2),
            (3, 5),
            (4, 64),
            (5, 100),
            (6, 8),
            (7, 9),
            (8, 513),
            (9, 4100),
        ];
        for (seed, capacity) in cases {
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
    fn many_searches_at_once_give_what_one_at_a_time_gives() {
        for (seed, capacity) in [(11u64, 1usize), (12, 7), (13, 8), (14, 65), (15, 5000)] {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut tree = SumTree::new(capacity);
            let mut slots = vec![usize::MAX; 100];
            assert!(!tree.find_many(&[0.5; 100], &mut slots));
            assert!(slots.iter().all(|&s| s == usize::MAX), "left as it was");
            for _ in 0..capacity.min(500) {
                let slot = rng.random_range(0..capacity);
                let weight = if rng.random::<f64>() < 0.3 {
                    0.0
                } else {
                    rng.random_range(0.0..5.0)
                };
                tree.set(slot, weight);
            }
            if tree.total() == 0.0 {
                tree.set(capacity - 1, 1.0);
            }
            // Inside the total, at and past it, below 0; batches longer than the lanes and
            // of odd lengths.
            for n in [1, 31, 32, 33, 100] {
                let prefixes: Vec<f64> = (0..n)
                    .map(|_| rng.random_range(-0.1..1.1) * tree.total())
                    .collect();
                let mut slots = vec![0; n];
                assert!(tree.find_many(&prefixes, &mut slots));
                for (prefix, slot) in prefixes.iter().zip(&slots) {
                    assert_eq!(Some(*slot), tree.find(*prefix), "prefix {prefix}");
                    assert!(tree.get(*slot) > 0.0);
                }
            }
        }
    }

    #[test]
    fn sums_after_many_updates_are_those_rebuilt_from_the_weights() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let mut tree = SumTree::new(777);
        for _ in 0..20_000 {
            tree.set(rng.random_range(0..777), rng.random_range(0.0..3.0));
        }
        let weights: Vec<f64> = tree.clone().into();
        assert_eq!(weights.len(), 777);
        let rebuilt = SumTree::try_from(weights.clone()).unwrap();
        assert_eq!(rebuilt, tree);
        let naive: f64 = weights.iter().sum();
        assert!((tree.total() - naive).abs() <= 1e-9 * naive);
    }

    #[test]
    fn setting_runs_of_slots_is_setting_them_one_by_one() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for capacity in [1, 7, 8, 9, 64, 65, 1000] {
            let (mut many, mut one) = (SumTree::new(capacity), SumTree::new(capacity));
            for _ in 0..200 {
                let start = rng.random_range(0..capacity);
                let len = rng.random_range(0..=capacity - start);
                let weights: Vec<f64> = (0..len).map(|_| rng.random_range(0.0..4.0)).collect();
                many.set_many(start, &weights);
                for (slot, &w) in (start..).zip(&weights) {
                    one.set(slot, w);
                }
                assert_eq!(many, one, "capacity {capacity}, {len} slots from {start}");
            }
        }
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
