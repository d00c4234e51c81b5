//! One primitive's storage in the replay: a fixed-capacity ring of transitions with their
//! generations and priorities. The sum trees over it live in
//! [`PrioritizedReplay`](crate::replay::PrioritizedReplay), which keeps both in step.

use experience::{Key, StoredTransition};
use sim::Primitive;

use crate::chunks::SharedChunks;
use crate::sum_tree::SumTree;

/// Fixed-capacity storage of one primitive: a ring of transitions, their generations and
/// priorities, all in shared chunks, so that a copy (a snapshot's) is cheap
/// ([`SharedChunks`]). Its sum trees are kept beside it
/// ([`PrioritizedReplay`](crate::replay::PrioritizedReplay)). Snapshots write each shared
/// observation once ([`crate::snapshot`]).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Ring {
    pub(crate) items: SharedChunks<StoredTransition>,
    /// The generation of the item in each slot.
    pub(crate) generations: SharedChunks<u64>,
    /// The priority of each slot after the epsilon floor (the tree holds it raised to alpha).
    pub(crate) priorities: SharedChunks<f64>,
    pub(crate) capacity: usize,
    /// Inserts so far: the next item's generation, and (mod capacity) its slot.
    pub(crate) inserted: u64,
    /// The largest priority given so far (before alpha), for items inserted without one.
    pub(crate) max_priority: f64,
}

impl Ring {
    pub(crate) fn new(capacity: usize) -> Self {
        // Items come in chunks as slots fill: a large ring never copies itself to grow (nor
        // holds its old and new copies at once).
        Self {
            items: SharedChunks::default(),
            generations: SharedChunks::default(),
            priorities: SharedChunks::default(),
            capacity,
            inserted: 0,
            // Schaul et al. start at 1: new experience is seen at least once early on.
            max_priority: 1.0,
        }
    }

    pub(crate) fn capacity(&self) -> usize {
        self.capacity
    }

    /// The slot `key` names if it still holds the item it was issued for.
    pub(crate) fn live_slot(&self, key: &Key) -> Option<usize> {
        let slot = key.slot as usize;
        (self.generations.get(slot) == Some(&key.generation)).then_some(slot)
    }

    /// Puts an item in the next slot (the oldest when full) with its priority floored at
    /// `epsilon`, or the largest so far; returns the slot, its generation and the priority.
    /// The caller sets the slot's weight in its tree.
    pub(crate) fn put(
        &mut self,
        transition: StoredTransition,
        priority: Option<f64>,
        epsilon: f64,
    ) -> (usize, u64, f64) {
        let p = priority.unwrap_or(self.max_priority).max(epsilon);
        self.max_priority = self.max_priority.max(p);
        let generation = self.inserted;
        let slot = (generation % self.capacity() as u64) as usize;
        if slot == self.items.len() {
            self.items.push(transition);
            self.generations.push(generation);
            self.priorities.push(p);
        } else {
            self.items.set(slot, transition);
            self.generations.set(slot, generation);
            self.priorities.set(slot, p);
        }
        self.inserted += 1;
        (slot, generation, p)
    }

    /// The first damaged observation, named by its slot: the items' own first, then
    /// their successors' (mostly other items' own, read back as one).
    pub(crate) fn check_observations(&self, primitive: Primitive) -> Result<(), String> {
        let items = || self.items.iter().enumerate();
        let own = items().map(|(slot, item)| (slot, item, &item.obs, ""));
        let next = items().filter_map(|(slot, item)| {
            let next = item.next.as_ref()?;
            Some((slot, item, &next.obs, ", its next step's"))
        });
        own.chain(next).try_for_each(|(slot, item, obs, whose)| {
            obs.check().map_err(|why| {
                format!(
                    "the {primitive:?} ring's observation at slot {slot} (episode {}, step {}{whose}): \
                     {why}",
                    item.episode, item.step
                )
            })
        })
    }

    pub(crate) fn check(&self, capacity: usize) -> Result<(), String> {
        let len = self.items.len();
        let expected = usize::try_from(self.inserted).map_or(capacity, |n| n.min(capacity));
        if self.capacity != capacity
            || len != expected
            || self.generations.len() != len
            || self.priorities.len() != len
        {
            return Err(format!(
                "a ring of capacity {} holds {len} items and {} generations after {} inserts, \
                 the config says capacity {capacity}",
                self.capacity,
                self.generations.len(),
                self.inserted
            ));
        }
        // Their sum tree is built from them: a bad one would corrupt every sum above it.
        if let Some(bad) = self
            .priorities
            .iter()
            .find(|p| !(p.is_finite() && **p >= 0.0))
        {
            return Err(format!("a priority of {bad}"));
        }
        Ok(())
    }

    /// The sum trees of the ring's priorities raised to `alpha`, one per kind of reward
    /// (`kinds` of them; `kind` says an item's): an item weighs in its kind's tree only.
    pub(crate) fn trees(
        &self,
        alpha: f64,
        kinds: usize,
        kind: impl Fn(&StoredTransition) -> usize,
    ) -> Vec<SumTree> {
        let mut weights = vec![vec![0.0; self.items.len()]; kinds];
        for (slot, (item, p)) in self.items.iter().zip(self.priorities.iter()).enumerate() {
            weights[kind(item)][slot] = p.powf(alpha);
        }
        weights
            .iter()
            .map(|weights| {
                let mut tree = SumTree::new(self.capacity);
                tree.set_many(0, weights);
                tree
            })
            .collect()
    }
}
