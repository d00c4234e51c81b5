//! Proportional prioritised replay (Schaul et al.; Ape-X's initial priorities): one ring and
//! one sum tree per primitive, so push and grasp batches are drawn from their own experience
//! at their own priorities. With a positive share (`[buffer] positive_share`), each ring has
//! two trees, one per kind of reward, and a batch draws that share from the positive one.
//!
//! The rings (their storage, `ring.rs`) and the prioritised replay over them are one
//! structure: every method here keeps the rings, the sum trees and the counts in step.

use experience::{BatchItem, Key};
use rand::{Rng, RngExt};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sim::{ConfigError, Primitive};

use crate::config::BufferConfig;
use crate::error::ReplayError;
use crate::ring::Ring;
use crate::sum_tree::SumTree;
use experience::StoredTransition;

/// A batch of one primitive, drawn with replacement.
#[derive(Clone, Debug, PartialEq)]
pub struct Batch<'a> {
    pub items: Vec<BatchItem<&'a StoredTransition>>,
    /// Each item's P(i) = p_i^alpha / sum_k p_k^alpha at the time of sampling.
    pub probabilities: Vec<f64>,
    /// The beta the weights were computed with.
    pub beta: f64,
}

impl Batch<'_> {
    /// The items owned, their observations still packed (shared with the rings), as a
    /// message carries them to the learner.
    pub fn to_owned_items(&self) -> Vec<BatchItem<StoredTransition>> {
        self.items
            .iter()
            .map(|item| BatchItem {
                key: item.key,
                weight: item.weight,
                transition: item.transition.clone(),
            })
            .collect()
    }

    /// The items with their observations decompressed (in parallel), as the learner trains
    /// on them; a damaged observation is an error naming its item.
    pub fn unpack(&self) -> Result<Vec<BatchItem>, ReplayError> {
        unpack(&self.to_owned_items())
    }
}

/// `items` with their observations decompressed, in parallel; a damaged observation is an
/// error naming its item.
pub fn unpack(items: &[BatchItem<StoredTransition>]) -> Result<Vec<BatchItem>, ReplayError> {
    items
        .par_iter()
        .map(|item| {
            item.unpack()
                .map_err(|why| ReplayError::Corrupt { key: item.key, why })
        })
        .collect()
}

/// The sum trees of the two rings (push, grasp), each ring's one per kind of reward: their
/// priorities raised to alpha, a function of the rings. Left out of a snapshot's copy and
/// file, rebuilt when it is read.
#[derive(Debug, Default, PartialEq)]
struct Trees(Vec<Vec<SumTree>>);

/// Kinds of reward a ring's trees tell apart: two with a positive share, else one.
fn kinds(positive_share: Option<f64>) -> usize {
    if positive_share.is_some() { 2 } else { 1 }
}

/// Writes a run of consecutive slots from `start` into a ring's trees: each slot's weight
/// into its kind's tree, 0 into the others'.
fn set_run(trees: &mut [SumTree], start: usize, run: &[(usize, f64)]) {
    for (k, tree) in trees.iter_mut().enumerate() {
        let weights: Vec<f64> = run
            .iter()
            .map(|&(kind, weight)| if kind == k { weight } else { 0.0 })
            .collect();
        tree.set_many(start, &weights);
    }
}

/// Push and grasp rings with proportional prioritisation and annealed importance sampling.
#[derive(Debug, PartialEq, Serialize, Deserialize)]
pub struct PrioritizedReplay {
    alpha: f64,
    beta_start: f64,
    beta_anneal_samples: u64,
    epsilon: f64,
    push: Ring,
    grasp: Ring,
    /// The share of each batch drawn from positive rewards; `None`: one tree a ring.
    positive_share: Option<f64>,
    /// Items sampled so far over both primitives: the clock of beta's annealing.
    sampled: u64,
    /// Priority updates dropped because their slot had been overwritten (or never existed).
    stale_updates: u64,
    #[serde(skip)]
    trees: Trees,
}

impl PrioritizedReplay {
    /// Empty rings of the config's capacity each (in transitions: see
    /// [`BufferConfig::resolve`]).
    pub fn new(config: &BufferConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        let slots = config.slots()?;
        let trees = || {
            (0..kinds(config.positive_share))
                .map(|_| SumTree::new(slots))
                .collect()
        };
        Ok(Self {
            alpha: config.alpha,
            beta_start: config.beta_start,
            beta_anneal_samples: config.beta_anneal_samples,
            epsilon: config.priority_epsilon,
            push: Ring::new(slots),
            grasp: Ring::new(slots),
            positive_share: config.positive_share,
            sampled: 0,
            stale_updates: 0,
            trees: Trees(vec![trees(), trees()]),
        })
    }

    /// A copy to save (a snapshot's): the rings share their chunks with this replay's, and
    /// the sum trees are left behind, so it takes microseconds at any size. It cannot sample.
    pub(crate) fn copy_to_save(&self) -> Self {
        Self {
            push: self.push.clone(),
            grasp: self.grasp.clone(),
            trees: Trees::default(),
            ..*self
        }
    }

    /// Builds the sum trees from the rings' priorities (a snapshot just read).
    pub(crate) fn rebuild_trees(&mut self) {
        let (kinds, kind) = (kinds(self.positive_share), self.kind_of());
        self.trees = Trees(vec![
            self.push.trees(self.alpha, kinds, kind),
            self.grasp.trees(self.alpha, kinds, kind),
        ]);
    }

    /// The tree an item weighs in: 1 for a positive reward when kinds are told apart, else 0.
    fn kind_of(&self) -> impl Fn(&StoredTransition) -> usize + Copy + use<> {
        let split = self.positive_share.is_some();
        move |item| usize::from(split && item.reward > 0.0)
    }

    fn trees(&self, primitive: Primitive) -> &[SumTree] {
        &self.trees.0[primitive as usize]
    }

    /// The ring of `primitive` and its sum trees.
    fn ring_and_trees_mut(&mut self, primitive: Primitive) -> (&mut Ring, &mut [SumTree]) {
        let trees = &mut self.trees.0[primitive as usize];
        match primitive {
            Primitive::Push => (&mut self.push, trees),
            Primitive::Grasp => (&mut self.grasp, trees),
        }
    }

    fn ring(&self, primitive: Primitive) -> &Ring {
        match primitive {
            Primitive::Push => &self.push,
            Primitive::Grasp => &self.grasp,
        }
    }

    /// Slots per primitive.
    pub fn capacity(&self) -> usize {
        self.push.capacity()
    }

    /// Transitions held for `primitive`.
    pub fn len(&self, primitive: Primitive) -> usize {
        self.ring(primitive).items.len()
    }

    /// Whether nothing of `primitive` is held.
    pub fn is_empty(&self, primitive: Primitive) -> bool {
        self.len(primitive) == 0
    }

    /// Transitions ever inserted for `primitive`, overwritten ones included.
    pub fn inserted(&self, primitive: Primitive) -> u64 {
        self.ring(primitive).inserted
    }

    /// Items sampled so far, both primitives.
    pub fn sampled(&self) -> u64 {
        self.sampled
    }

    /// Priority updates ignored because their item was gone.
    pub fn stale_updates(&self) -> u64 {
        self.stale_updates
    }

    /// The beta the next batch gets: `beta_start`, rising linearly with sampled items to 1
    /// after `beta_anneal_samples`.
    pub fn beta(&self) -> f64 {
        if self.sampled >= self.beta_anneal_samples {
            return 1.0;
        }
        let progress = self.sampled as f64 / self.beta_anneal_samples as f64;
        self.beta_start + (1.0 - self.beta_start) * progress
    }

    /// The priority of a live item (after the epsilon floor, before alpha).
    pub fn priority(&self, key: &Key) -> Option<f64> {
        let ring = self.ring(key.primitive);
        ring.live_slot(key).map(|slot| ring.priorities[slot])
    }

    /// The stored transition a key names, while it is still there.
    pub fn get(&self, key: &Key) -> Option<&StoredTransition> {
        let ring = self.ring(key.primitive);
        ring.live_slot(key).map(|slot| &ring.items[slot])
    }

    /// Stores a transition in its primitive's ring, overwriting the oldest when full, at
    /// `priority` (the actor's |TD error|, Ape-X) or, without one, the largest priority
    /// given so far. Priorities below epsilon are raised to it.
    pub fn insert(
        &mut self,
        transition: StoredTransition,
        priority: Option<f64>,
    ) -> Result<Key, ReplayError> {
        let keys = self.insert_many(vec![(transition, priority)])?;
        Ok(keys[0])
    }

    /// [`insert`](Self::insert) for many transitions, in order, their keys in the same
    /// order; none is stored when a priority is bad. The sums above each run of
    /// consecutive slots are updated once ([`SumTree::set_many`]), which makes a batch of
    /// inserts several times faster than as many single ones.
    pub fn insert_many(
        &mut self,
        items: Vec<(StoredTransition, Option<f64>)>,
    ) -> Result<Vec<Key>, ReplayError> {
        for (_, priority) in &items {
            if let Some(p) = priority {
                check_priority(*p)?;
            }
        }
        let (alpha, epsilon, kind_of) = (self.alpha, self.epsilon, self.kind_of());
        let mut keys = Vec::with_capacity(items.len());
        // Per primitive, the first slot of the run not yet in the trees and its kinds and
        // weights.
        let mut runs: [(usize, Vec<(usize, f64)>); 2] = Default::default();
        for (transition, priority) in items {
            let primitive = transition.primitive();
            let kind = kind_of(&transition);
            let (ring, trees) = self.ring_and_trees_mut(primitive);
            let (slot, generation, p) = ring.put(transition, priority, epsilon);
            let (start, run) = &mut runs[primitive as usize];
            if *start + run.len() != slot {
                set_run(trees, *start, run);
                (*start, *run) = (slot, Vec::new());
            }
            run.push((kind, p.powf(alpha)));
            keys.push(Key {
                primitive,
                slot: slot as u32,
                generation,
            });
        }
        for (primitive, (start, run)) in [Primitive::Push, Primitive::Grasp].into_iter().zip(runs) {
            set_run(self.ring_and_trees_mut(primitive).1, start, &run);
        }
        Ok(keys)
    }

    /// Sets the priority of the item `key` names (floored at epsilon); returns false, and
    /// counts a stale update, when that item has been overwritten.
    pub fn update_priority(&mut self, key: &Key, priority: f64) -> Result<bool, ReplayError> {
        check_priority(priority)?;
        let (alpha, epsilon, kind_of) = (self.alpha, self.epsilon, self.kind_of());
        let (ring, trees) = self.ring_and_trees_mut(key.primitive);
        let Some(slot) = ring.live_slot(key) else {
            self.stale_updates += 1;
            return Ok(false);
        };
        let p = priority.max(epsilon);
        ring.max_priority = ring.max_priority.max(p);
        ring.priorities.set(slot, p);
        // One tree a ring needs no look at the item (a scattered read).
        let kind = if trees.len() == 1 {
            0
        } else {
            kind_of(&ring.items[slot])
        };
        trees[kind].set(slot, p.powf(alpha));
        Ok(true)
    }

    /// Draws `n` items of `primitive` with replacement, with probability proportional to
    /// priority^alpha, one from each of `n` equal strata of the total (lower variance than
    /// independent draws, the same marginal probabilities), and their importance-sampling
    /// weights at the current beta. With a positive share, that share of the draws (in
    /// expectation) comes from the positive rewards' tree and the rest from the other's,
    /// each so drawn; the weights still undo priority alone. Advances beta's clock by `n`.
    pub fn sample(
        &mut self,
        primitive: Primitive,
        n: usize,
        rng: &mut impl Rng,
    ) -> Result<Batch<'_>, ReplayError> {
        if n == 0 {
            return Err(ReplayError::EmptyBatch);
        }
        if self.is_empty(primitive) {
            return Err(ReplayError::Empty(primitive));
        }
        let beta = self.beta();
        self.sampled += n as u64;
        let ring = self.ring(primitive);
        let len = ring.items.len() as f64;
        let mut batch = Batch {
            items: Vec::with_capacity(n),
            probabilities: Vec::with_capacity(n),
            beta,
        };
        let trees = self.trees(primitive);
        // Zipped with the trees: a ring of one tree takes the first share alone.
        let shares = self.kind_shares(trees);
        // The weights undo priority alone, as without a share: the share is meant to change
        // what is learned from, as the authors' replay does.
        let total: f64 = trees.iter().map(SumTree::total).sum();

        let mut left = n;
        for (k, (tree, share)) in trees.iter().zip(shares).enumerate() {
            let draws = if k + 1 == trees.len() {
                left
            } else {
                // The share's whole draws, and one more with its fraction's probability.
                let expected = n as f64 * share;
                let whole = expected.floor();
                whole as usize + usize::from(rng.random::<f64>() < expected - whole)
            };
            left -= draws;
            let tree_total = tree.total();
            draw(tree, ring, draws, rng, |slot, generation| {
                let weight = tree.get(slot);
                batch.probabilities.push(share * (weight / tree_total));
                batch.items.push(BatchItem {
                    key: Key {
                        primitive,
                        slot: slot as u32,
                        generation,
                    },
                    weight: (len * (weight / total)).powf(-beta) as f32,
                    transition: &ring.items[slot],
                });
            });
        }
        let max_weight = batch.items.iter().map(|i| i.weight).fold(0.0f32, f32::max);
        for item in &mut batch.items {
            item.weight /= max_weight;
        }
        Ok(batch)
    }

    /// The expected share of a batch each of a ring's trees gives: all from the one tree,
    /// or the positive share from the positive tree, the whole batch from one whose other
    /// is empty.
    fn kind_shares(&self, trees: &[SumTree]) -> [f64; 2] {
        match (self.positive_share, trees) {
            (Some(share), [other, positive]) => {
                let positive = match (other.total() > 0.0, positive.total() > 0.0) {
                    (true, true) => share,
                    (false, _) => 1.0,
                    (true, false) => 0.0,
                };
                [1.0 - positive, positive]
            }
            _ => [1.0, 0.0],
        }
    }

    /// Checks every stored observation's bytes against its hash (a snapshot just read).
    pub(crate) fn check_observations(&self) -> Result<(), String> {
        self.push.check_observations(Primitive::Push)?;
        self.grasp.check_observations(Primitive::Grasp)
    }

    /// Checks the invariants a snapshot must satisfy against the config it carries (before
    /// [`rebuild_trees`](Self::rebuild_trees)).
    pub(crate) fn check(&self, config: &BufferConfig) -> Result<(), String> {
        let slots = config.slots().map_err(|e| e.to_string())?;
        self.push.check(slots)?;
        self.grasp.check(slots)?;
        let rings = [
            (&self.push, Primitive::Push),
            (&self.grasp, Primitive::Grasp),
        ];
        for (ring, primitive) in rings {
            if ring.items.iter().any(|t| t.primitive() != primitive) {
                return Err(format!("the {primitive:?} ring holds another primitive"));
            }
        }
        Ok(())
    }
}

/// Draws `n` slots from `tree`, one from each of `n` equal strata of its total, and hands
/// each to `visit` with its generation in `ring`.
fn draw(
    tree: &SumTree,
    ring: &Ring,
    n: usize,
    rng: &mut impl Rng,
    mut visit: impl FnMut(usize, u64),
) {
    // Every live slot of a tree drawn from has at least epsilon^alpha > 0, so its total is
    // positive.
    let stratum = tree.total() / n as f64;
    // The searches run a chunk at a time (`SumTree::find_many`), from scratch space on the
    // stack.
    const CHUNK: usize = 64;
    let mut prefixes = [0.0f64; CHUNK];
    let mut slots = [0usize; CHUNK];
    let mut generations = [0u64; CHUNK];
    for start in (0..n).step_by(CHUNK) {
        let m = CHUNK.min(n - start);
        for (k, prefix) in prefixes[..m].iter_mut().enumerate() {
            *prefix = ((start + k) as f64 + rng.random::<f64>()) * stratum;
        }
        let found = tree.find_many(&prefixes[..m], &mut slots[..m]);
        assert!(found, "total is positive");
        // A loop of bare loads, so that the scattered reads overlap.
        for (generation, &slot) in generations.iter_mut().zip(&slots[..m]) {
            *generation = ring.generations[slot];
        }
        for (&slot, &generation) in slots[..m].iter().zip(&generations) {
            visit(slot, generation);
        }
    }
}

fn check_priority(p: f64) -> Result<(), ReplayError> {
    if p.is_finite() && p >= 0.0 {
        Ok(())
    } else {
        Err(ReplayError::BadPriority(p))
    }
}
