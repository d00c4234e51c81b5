//! The buffer role's state: the replay, each actor incarnation's stream, the learner's
//! requests waiting, every episode's outcome; what each message does to it, and how it is
//! saved beside the replay's snapshot.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::PathBuf;
use std::thread::JoinHandle;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use buffer::{ReplayBuffer, ReplayCopy, Serving};
use mcaplog::RunLog;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use wire::{
    BatchMessage, Control, EpisodeEnd, Inbox, Message, Origin, Outbox, Role, SampleRequest, Status,
    Step,
};

use rundir::config::RunConfig;
use rundir::record::BUFFER_STATS;
use rundir::run_dir::{RunDir, keep_previous, newest_or_previous, previous};
use rundir::{BufferReport, SUCCESS_WINDOW, StreamCount, read_json, write_json};

/// The share of goal grasps among `outcomes`.
fn success(outcomes: &[bool]) -> Option<f64> {
    (!outcomes.is_empty())
        .then(|| outcomes.iter().filter(|&&s| s).count() as f64 / outcomes.len() as f64)
}

/// The launcher's stop orders read in one go.
#[derive(Default)]
pub(super) struct Orders {
    /// The buffer stops now.
    pub(super) stop: bool,
    /// The actors are stopping: everything they send must be let in.
    pub(super) actors_stopped: bool,
}

pub(super) struct BufferRole {
    pub(super) replay: ReplayBuffer,
    pub(super) report: BufferReport,
    /// Per (actor, incarnation): its stream position and its episodes still open.
    pub(super) streams: BTreeMap<(u32, u32), (StreamCount, BTreeSet<u64>)>,
    pub(super) requests: VecDeque<SampleRequest>,
    pub(super) rng: ChaCha8Rng,
    /// Every episode's outcome in arrival order (true: the goal was grasped).
    pub(super) outcomes: Vec<bool>,
    /// The snapshot being written in the background, if one is.
    writer: Option<JoinHandle<Result<()>>>,
    /// How many times the buffer was started before in the run.
    incarnation: u32,
    /// The streams a restarted buffer has heard from: the gap before a stream's first
    /// message here is what the restart lost (the first buffer of a run keeps none).
    heard: BTreeSet<(u32, u32)>,
}

impl BufferRole {
    pub(super) fn new(config: &RunConfig, incarnation: u32) -> Result<Self> {
        let serving = Serving {
            push_reward: config.push_reward,
            sampled: config
                .trained_nets()
                .iter()
                .map(|n| n.primitive())
                .collect(),
            successors: config.learning.target_update_every > 0,
        };
        Ok(Self {
            replay: ReplayBuffer::new(config.buffer.clone(), serving)?,
            report: BufferReport::default(),
            streams: BTreeMap::new(),
            requests: VecDeque::new(),
            rng: ChaCha8Rng::seed_from_u64(config.seed ^ 0xb0ff),
            outcomes: Vec::new(),
            writer: None,
            incarnation,
            heard: BTreeSet::new(),
        })
    }

    /// The replay, counters and open episodes the run directory's snapshot holds. A damaged
    /// newest snapshot or its counters: the previous pair, and the warning returned.
    pub(super) fn restore(&mut self, dir: &RunDir) -> Result<Option<String>> {
        let ((replay, saved), warning) = newest_or_previous(&dir.snapshot(), |before| {
            let pick = |path: PathBuf| if before { previous(&path) } else { path };
            let replay = ReplayBuffer::load(&pick(dir.snapshot()))?;
            let saved: SavedState = read_json(&pick(dir.buffer_counters()))?;
            Ok((replay, saved))
        })?;
        self.replay = replay;
        self.report = saved.report;
        self.outcomes = saved.outcomes;
        let open: BTreeMap<(u32, u32), Vec<u64>> = saved.open.into_iter().collect();
        for count in &self.report.streams {
            let key = (count.actor, count.incarnation);
            let episodes = open.get(&key).cloned().unwrap_or_default();
            self.streams
                .insert(key, (count.clone(), episodes.into_iter().collect()));
        }
        Ok(warning)
    }

    /// Carries out the launcher's orders (a snapshot at once); which of them stop something.
    pub(super) fn obey(&mut self, control: &mut Inbox, dir: &RunDir) -> Result<Orders> {
        let mut orders = Orders::default();
        for message in control.drain()? {
            match message {
                Message::Control(Control::Stop(Role::Actor)) => orders.actors_stopped = true,
                Message::Control(Control::Stop(Role::Buffer)) => orders.stop = true,
                Message::Control(Control::Snapshot) => self.save(dir)?,
                _ => {}
            }
        }
        Ok(orders)
    }

    /// Queues the learner's sample requests and applies its priority updates; whether any
    /// came.
    pub(super) fn take_requests(&mut self, requests: &mut Inbox) -> Result<bool> {
        let messages = requests.drain()?;
        for message in &messages {
            match message {
                Message::SampleRequest(request) => self.requests.push_back(*request),
                Message::PriorityUpdate(update) => {
                    self.replay.update_priorities(&update.updates)?;
                    self.report.priority_updates += 1;
                }
                other => bail!("the requests topic carried {other:?}"),
            }
        }
        Ok(!messages.is_empty())
    }

    /// The status to the launcher, the counters to the log.
    pub(super) fn report_to(&mut self, status: &mut Outbox, log: &RunLog) -> Result<()> {
        status.send(&Message::Status(self.status()))?;
        log.json(BUFFER_STATS, &self.report)?;
        Ok(())
    }

    /// Checks a message's place in its sender's stream; a new incarnation of an actor
    /// flushes what its predecessors left open.
    pub(super) fn arrive(&mut self, origin: Origin) -> Result<&mut (StreamCount, BTreeSet<u64>)> {
        let key = (origin.actor, origin.incarnation);
        if !self.streams.contains_key(&key) {
            let stale: Vec<(u32, u32)> = self
                .streams
                .keys()
                .filter(|(a, i)| *a == origin.actor && *i < origin.incarnation)
                .copied()
                .collect();
            for old in stale {
                let open = std::mem::take(&mut self.streams.get_mut(&old).expect("listed").1);
                for episode in open {
                    self.replay.flush_episode(episode);
                }
            }
        }
        let (count, _) = self.streams.entry(key).or_insert_with(|| {
            (
                StreamCount {
                    actor: origin.actor,
                    incarnation: origin.incarnation,
                    ..StreamCount::default()
                },
                BTreeSet::new(),
            )
        });
        if origin.seq < count.next_seq {
            bail!(
                "actor {} (incarnation {}) sent sequence number {} twice",
                origin.actor,
                origin.incarnation,
                origin.seq
            );
        }
        let gap = origin.seq - count.next_seq;
        if self.incarnation > 0 && self.heard.insert(key) {
            count.lost_in_restart += gap;
            *self
                .report
                .restart_losses
                .entry(self.incarnation)
                .or_default() += gap;
        } else {
            count.missing += gap;
        }
        count.next_seq = origin.seq + 1;
        Ok(self.streams.get_mut(&key).expect("inserted"))
    }

    pub(super) fn step(&mut self, step: Step) -> Result<()> {
        let episode = step.transition.episode;
        let (count, open) = self.arrive(step.origin)?;
        count.steps += 1;
        open.insert(episode);
        self.report.steps_received += 1;
        self.replay
            .add_step(step.transition, Some(step.priority))
            .context("a step from an actor")?;
        Ok(())
    }

    pub(super) fn episode_end(&mut self, end: EpisodeEnd) -> Result<()> {
        let (_, open) = self.arrive(end.origin)?;
        open.remove(&end.episode);
        if let Err(e) = self.replay.end_episode(end.episode, end.grasped) {
            // Keep the steps; only their relabelled copies are lost.
            eprintln!(
                "buffer: episode {}: {e}; stored without relabelling",
                end.episode
            );
            self.replay.flush_episode(end.episode);
        }
        if end.trial {
            self.report.trials += 1;
            return Ok(());
        }
        self.report.episodes += 1;
        self.report.goal_grasps += u64::from(end.goal_grasped());
        self.outcomes.push(end.goal_grasped());
        Ok(())
    }

    /// Answers the oldest request once the rate limiter allows it: with a batch, or with no
    /// items while the replay holds none of its primitive (in stage 3 the policy may not
    /// have pushed yet; the learner then trains the other net instead of waiting).
    pub(super) fn serve(&mut self, batches: &mut Outbox) -> Result<bool> {
        let Some(&request) = self.requests.front() else {
            return Ok(false);
        };
        let size = request.size as usize;
        if !self.replay.can_sample(size as u64) {
            return Ok(false);
        }
        let items = if self.replay.replay().is_empty(request.primitive) {
            Vec::new()
        } else {
            let batch = self.replay.sample(request.primitive, size, &mut self.rng)?;
            batch.to_owned_items()
        };
        self.requests.pop_front();
        batches.send(&Message::Batch(BatchMessage {
            request: request.id,
            items,
        }))?;
        Ok(true)
    }

    pub(super) fn sync_report(&mut self) {
        let stats = self.replay.stats();
        self.report.inserted = stats.inserted;
        self.report.relabelled = stats.relabelled;
        self.report.sampled = stats.sampled;
        self.report.streams = self.streams.values().map(|(c, _)| c.clone()).collect();
        self.report.lost_in_restarts = self.report.streams.iter().map(|s| s.lost_in_restart).sum();
        let n = self.outcomes.len();
        self.report.success_first30 = success(&self.outcomes[..n.min(SUCCESS_WINDOW)]);
        self.report.success_last30 = success(&self.outcomes[n.saturating_sub(SUCCESS_WINDOW)..]);
    }

    pub(super) fn status(&mut self) -> Status {
        self.sync_report();
        let stats = self.replay.stats();
        Status::Buffer {
            steps_received: self.report.steps_received,
            episodes: self.report.episodes,
            success_last30: self.report.success_last30,
            inserted: stats.inserted,
            stored: (stats.push_len + stats.grasp_len) as u64,
            capacity: 2 * self.replay.replay().capacity() as u64,
            relabelled: stats.relabelled,
            lost: self.report.lost(),
        }
    }

    /// Writes a snapshot now, after any still being written in the background.
    pub(super) fn save(&mut self, dir: &RunDir) -> Result<()> {
        let start = Instant::now();
        self.finish_writing()?;
        self.snapshot().write(dir)?;
        self.held(start);
        Ok(())
    }

    /// Starts writing a snapshot in the background from a copy taken now (the packed
    /// observations are shared, not copied), unless one is still being written.
    pub(super) fn save_in_background(&mut self, dir: &RunDir) -> Result<()> {
        if self.writer.as_ref().is_some_and(|w| !w.is_finished()) {
            return Ok(());
        }
        self.finish_writing()?;
        let start = Instant::now();
        let snapshot = self.snapshot();
        self.held(start);
        let dir = dir.clone();
        self.writer = Some(std::thread::spawn(move || snapshot.write(&dir)));
        Ok(())
    }

    /// Waits for the background snapshot, if one is being written; its error, if it failed.
    fn finish_writing(&mut self) -> Result<()> {
        match self.writer.take() {
            Some(writer) => writer.join().expect("the snapshot writer does not panic"),
            None => Ok(()),
        }
    }

    fn held(&mut self, since: Instant) {
        let ms = since.elapsed().as_secs_f64() * 1e3;
        self.report.snapshot_hold_ms_max = self.report.snapshot_hold_ms_max.max(ms);
    }

    /// The buffer as it stands: the replay and the counters that go with it.
    fn snapshot(&mut self) -> Snapshot {
        self.report.snapshots += 1;
        self.sync_report();
        Snapshot {
            replay: self.replay.copy_to_save(),
            state: SavedState {
                report: self.report.clone(),
                open: self
                    .streams
                    .iter()
                    .map(|(k, (_, open))| (*k, open.iter().copied().collect()))
                    .collect(),
                outcomes: self.outcomes.clone(),
            },
        }
    }
}

/// A consistent copy of the buffer, to write.
struct Snapshot {
    replay: ReplayCopy,
    state: SavedState,
}

impl Snapshot {
    /// Writes the replay, its counters and the learning curve, keeping the previous
    /// generation of each.
    fn write(self, dir: &RunDir) -> Result<()> {
        keep_previous(&dir.snapshot())?;
        keep_previous(&dir.buffer_counters())?;
        self.replay.save(&dir.snapshot())?;
        write_json(&dir.buffer_counters(), &self.state)?;
        let outcomes = &self.state.outcomes;
        let mut curve = String::from("episode,goal_grasped,success_last30\n");
        for (i, &grasped) in outcomes.iter().enumerate() {
            let window = &outcomes[(i + 1).saturating_sub(SUCCESS_WINDOW)..=i];
            let rate = success(window).expect("not empty");
            curve.push_str(&format!("{},{},{rate:.4}\n", i + 1, u8::from(grasped)));
        }
        let path = dir.curve();
        std::fs::write(&path, curve).with_context(|| format!("writing {}", path.display()))
    }
}

/// The counters and open episodes, saved beside the replay snapshot.
#[derive(Serialize, Deserialize)]
struct SavedState {
    report: BufferReport,
    open: Vec<((u32, u32), Vec<u64>)>,
    outcomes: Vec<bool>,
}
