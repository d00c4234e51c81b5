//! The buffer as one value: the prioritised replay, the rate limiter and the episode
//! assembler, kept consistent with each other (what the buffer role runs and snapshots).

use experience::{Key, Transition};
use policy::PushReward;
use rand::Rng;
use serde::{Deserialize, Serialize};
use sim::{ConfigError, ObjectId, Primitive};

use crate::config::BufferConfig;
use crate::error::{AssembleError, ReplayError};
use crate::rate_limit::RateLimiter;
use crate::relabel::{EpisodeAssembler, Ready};
use crate::replay::{Batch, PrioritizedReplay};

/// Counters for progress displays and logs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stats {
    pub push_len: usize,
    pub grasp_len: usize,
    /// Items ever stored, relabelled copies included.
    pub inserted: u64,
    pub sampled: u64,
    pub relabelled: u64,
    pub stale_updates: u64,
    pub open_episodes: usize,
}

/// Prioritised replay with episode assembly, goal relabelling and a samples-per-insert limit.
///
/// Inserts are never refused (a step an actor sent must not be lost): the wiring pauses
/// reading its transport while [`can_insert`](Self::can_insert) says no. Sampling past the
/// ratio is refused with [`ReplayError::RateLimited`].
#[derive(Debug, PartialEq, Serialize, Deserialize)]
pub struct ReplayBuffer {
    config: BufferConfig,
    replay: PrioritizedReplay,
    limiter: RateLimiter,
    assembler: EpisodeAssembler,
    serving: Serving,
}

/// What the buffer must know of the run it serves, beyond its own config.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Serving {
    /// The run's push reward, which relabelled pushes earn too.
    pub push_reward: PushReward,
    /// The primitives the learner samples. Only their inserts count toward the rate limit:
    /// inserts nobody samples would hold the actors back for nothing (in stage 2 a grasp net
    /// sure of the goal grasps without pushing, and the push learner would wait forever).
    pub sampled: Vec<Primitive>,
    /// Whether the learner values pushes' next states itself (`[learning]
    /// target_update_every`): only then are pushes stored with their next step, so that
    /// otherwise no batch carries, and no learner unpacks, an observation nobody reads.
    pub successors: bool,
}

impl ReplayBuffer {
    /// An empty buffer for the run `serving` describes.
    pub fn new(config: BufferConfig, serving: Serving) -> Result<Self, ConfigError> {
        Ok(Self {
            replay: PrioritizedReplay::new(&config)?,
            limiter: config.rate_limiter()?,
            assembler: EpisodeAssembler::new(),
            config,
            serving,
        })
    }

    pub fn config(&self) -> &BufferConfig {
        &self.config
    }

    /// The stored transitions and their priorities.
    pub fn replay(&self) -> &PrioritizedReplay {
        &self.replay
    }

    /// The limiter's counts.
    pub fn limiter(&self) -> &RateLimiter {
        &self.limiter
    }

    /// Holds a step until its episode ends, with the actor's initial priority.
    pub fn add_step(
        &mut self,
        transition: Transition,
        priority: Option<f64>,
    ) -> Result<(), AssembleError> {
        self.assembler.add(transition, priority)
    }

    /// Ends an episode: stores its steps and, when the config relabels, their relabelled
    /// copies; returns their keys in the order of [`EpisodeAssembler::end`].
    pub fn end_episode(
        &mut self,
        episode: u64,
        grasped: Option<ObjectId>,
    ) -> Result<Vec<Key>, AssembleError> {
        let relabelling = self.config.relabel.then_some(self.serving.push_reward);
        let ready = self.assembler.end(episode, grasped, relabelling)?;
        Ok(self.store(ready))
    }

    /// Stores an episode's steps as they are (its actor died before the end).
    pub fn flush_episode(&mut self, episode: u64) -> Vec<Key> {
        let ready = self.assembler.flush(episode);
        self.store(ready)
    }

    fn store(&mut self, ready: Vec<Ready>) -> Vec<Key> {
        let mut lens = [Primitive::Push, Primitive::Grasp].map(|p| self.replay.len(p));
        for r in &ready {
            let primitive = r.transition.primitive();
            if self.serving.sampled.contains(&primitive) {
                let len = &mut lens[primitive as usize];
                if *len == self.replay.capacity() {
                    self.limiter.on_delete(1);
                } else {
                    *len += 1;
                }
                self.limiter.on_insert(1);
            }
        }
        let successors = self.serving.successors;
        let items = ready.into_iter().map(|r| {
            let mut transition = r.transition;
            if !successors {
                transition.next = None;
            }
            (transition, r.priority)
        });
        self.replay
            .insert_many(items.collect())
            .expect("priorities were checked when the step arrived")
    }

    /// Whether `n` more items may be inserted without outrunning the learner.
    pub fn can_insert(&self, n: u64) -> bool {
        self.limiter.can_insert(n)
    }

    /// Whether a batch of `n` may be drawn now.
    pub fn can_sample(&self, n: u64) -> bool {
        self.limiter.can_sample(n)
    }

    /// Draws a batch of `primitive` if the rate limiter allows `n` samples.
    pub fn sample(
        &mut self,
        primitive: Primitive,
        n: usize,
        rng: &mut impl Rng,
    ) -> Result<Batch<'_>, ReplayError> {
        if !self.limiter.can_sample(n as u64) {
            return Err(ReplayError::RateLimited {
                inserts: self.limiter.inserts(),
                samples: self.limiter.samples(),
            });
        }
        let batch = self.replay.sample(primitive, n, rng)?;
        self.limiter.on_sample(n as u64);
        Ok(batch)
    }

    /// Applies the learner's new priorities; returns how many still had their item.
    pub fn update_priorities(&mut self, updates: &[(Key, f64)]) -> Result<usize, ReplayError> {
        let mut applied = 0;
        for (key, priority) in updates {
            applied += usize::from(self.replay.update_priority(key, *priority)?);
        }
        Ok(applied)
    }

    pub fn stats(&self) -> Stats {
        Stats {
            push_len: self.replay.len(Primitive::Push),
            grasp_len: self.replay.len(Primitive::Grasp),
            inserted: self.replay.inserted(Primitive::Push)
                + self.replay.inserted(Primitive::Grasp),
            sampled: self.replay.sampled(),
            relabelled: self.assembler.relabelled(),
            stale_updates: self.replay.stale_updates(),
            open_episodes: self.assembler.open_episodes(),
        }
    }

    /// Checks that a restored buffer is consistent with its own config, then builds its
    /// sum trees.
    pub(crate) fn check_and_index(&mut self) -> Result<(), String> {
        self.config
            .validate()
            .map_err(|e| e.in_table("buffer").to_string())?;
        self.replay.check(&self.config)?;
        self.replay.rebuild_trees();
        Ok(())
    }

    /// A consistent copy to write while this buffer goes on (a background snapshot): its
    /// rings share their chunks with this buffer's, and its sum trees are left out (a
    /// snapshot does not hold them), so it takes microseconds at any size.
    pub fn copy_to_save(&self) -> ReplayCopy {
        ReplayCopy(Self {
            config: self.config.clone(),
            replay: self.replay.copy_to_save(),
            limiter: self.limiter.clone(),
            assembler: self.assembler.clone(),
            serving: self.serving.clone(),
        })
    }
}

/// A buffer's copy taken to be saved ([`ReplayBuffer::copy_to_save`]); it can only be saved.
#[derive(Debug)]
pub struct ReplayCopy(pub(crate) ReplayBuffer);
