//! The buffer role: receives every actor's steps, assembles and relabels episodes into the
//! prioritised replay, answers the learner's sample requests and applies its priority
//! updates, and snapshots on request and at shutdown.
//!
//! Every message on the steps topic carries its sender's sequence number, so the buffer
//! proves the transport lost nothing: per actor incarnation, what arrived is exactly 0..n.
//! When an actor index comes back as a new incarnation (its process was restarted), the
//! episodes the old one left open are stored as they are.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use buffer::{ReplayBuffer, Serving};
use mcaplog::RunLog;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use wire::{
    BatchMessage, Control, EpisodeEnd, Inbox, Message, Origin, Outbox, Role, SampleRequest, Status,
    Step, Topic, Transport,
};

use super::config::RunConfig;
use super::record::{BUFFER_EPISODE, BUFFER_STATS};
use super::run_dir::RunDir;
use super::{Lifeline, STATUS_EVERY, SUCCESS_WINDOW, read_json, write_json};

/// What one actor incarnation's stream delivered.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StreamCount {
    pub actor: u32,
    pub incarnation: u32,
    /// Steps received (episode ends not counted).
    pub steps: u64,
    /// The next sequence number expected.
    pub next_seq: u64,
    /// Sequence numbers that never arrived.
    pub missing: u64,
}

/// The buffer's counters: kept beside the replay snapshot and written as its report.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BufferReport {
    pub steps_received: u64,
    pub episodes: u64,
    pub goal_grasps: u64,
    /// Trial grasps' ends (`grasp_trials`): stored and relabelled, not counted in `episodes`.
    #[serde(default)]
    pub trials: u64,
    /// Goal grasp success over the run's first and last 30 episodes.
    pub success_first30: Option<f64>,
    pub success_last30: Option<f64>,
    pub streams: Vec<StreamCount>,
    pub inserted: u64,
    pub relabelled: u64,
    pub sampled: u64,
    pub priority_updates: u64,
    pub snapshots: u64,
}

impl BufferReport {
    pub fn lost(&self) -> u64 {
        self.streams.iter().map(|s| s.missing).sum()
    }
}

/// The share of goal grasps among `outcomes`.
fn success(outcomes: &[bool]) -> Option<f64> {
    (!outcomes.is_empty())
        .then(|| outcomes.iter().filter(|&&s| s).count() as f64 / outcomes.len() as f64)
}

struct BufferRole {
    replay: ReplayBuffer,
    report: BufferReport,
    /// Per (actor, incarnation): its stream position and its episodes still open.
    streams: BTreeMap<(u32, u32), (StreamCount, BTreeSet<u64>)>,
    requests: VecDeque<SampleRequest>,
    rng: ChaCha8Rng,
    /// Every episode's outcome in arrival order (true: the goal was grasped).
    outcomes: Vec<bool>,
}

impl BufferRole {
    fn new(config: &RunConfig) -> Result<Self> {
        let serving = Serving {
            push_reward: config.push_reward,
            sampled: config
                .trained_nets()
                .iter()
                .map(|n| n.primitive())
                .collect(),
        };
        Ok(Self {
            replay: ReplayBuffer::new(config.buffer.clone(), serving)?,
            report: BufferReport::default(),
            streams: BTreeMap::new(),
            requests: VecDeque::new(),
            rng: ChaCha8Rng::seed_from_u64(config.seed ^ 0xb0ff),
            outcomes: Vec::new(),
        })
    }

    /// The replay, counters and open episodes the run directory's snapshot holds.
    fn restore(&mut self, dir: &RunDir) -> Result<()> {
        self.replay = ReplayBuffer::load(&dir.snapshot())?;
        let saved: SavedState = read_json(&dir.buffer_counters())?;
        self.report = saved.report;
        self.outcomes = saved.outcomes;
        let open: BTreeMap<(u32, u32), Vec<u64>> = saved.open.into_iter().collect();
        for count in &self.report.streams {
            let key = (count.actor, count.incarnation);
            let episodes = open.get(&key).cloned().unwrap_or_default();
            self.streams
                .insert(key, (count.clone(), episodes.into_iter().collect()));
        }
        Ok(())
    }

    /// Carries out the launcher's orders; whether one stops the buffer.
    fn obey(&mut self, control: &mut Inbox, inflow: &mut Inflow, dir: &RunDir) -> Result<bool> {
        let mut stop = false;
        for message in control.drain()? {
            match message {
                Message::Control(Control::Stop(Role::Actor)) => inflow.actors_stopped = true,
                Message::Control(Control::Stop(Role::Buffer)) => stop = true,
                Message::Control(Control::Snapshot) => self.save(dir)?,
                _ => {}
            }
        }
        Ok(stop)
    }

    /// Queues the learner's sample requests and applies its priority updates; whether any
    /// came.
    fn take_requests(&mut self, requests: &mut Inbox) -> Result<bool> {
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
    fn report_to(&mut self, status: &mut Outbox, log: &RunLog) -> Result<()> {
        status.send(&Message::Status(self.status()))?;
        log.json(BUFFER_STATS, &self.report)?;
        Ok(())
    }

    /// Checks a message's place in its sender's stream; a new incarnation of an actor
    /// flushes what its predecessors left open.
    fn arrive(&mut self, origin: Origin) -> Result<&mut (StreamCount, BTreeSet<u64>)> {
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
        count.missing += origin.seq - count.next_seq;
        count.next_seq = origin.seq + 1;
        Ok(self.streams.get_mut(&key).expect("inserted"))
    }

    fn step(&mut self, step: Step) -> Result<()> {
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

    fn episode_end(&mut self, end: EpisodeEnd) -> Result<()> {
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
    fn serve(&mut self, batches: &mut Outbox) -> Result<bool> {
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
            batch.items.iter().map(|item| item.cloned()).collect()
        };
        self.requests.pop_front();
        batches.send(&Message::Batch(BatchMessage {
            request: request.id,
            items,
        }))?;
        Ok(true)
    }

    fn sync_report(&mut self) {
        let stats = self.replay.stats();
        self.report.inserted = stats.inserted;
        self.report.relabelled = stats.relabelled;
        self.report.sampled = stats.sampled;
        self.report.streams = self.streams.values().map(|(c, _)| c.clone()).collect();
        let n = self.outcomes.len();
        self.report.success_first30 = success(&self.outcomes[..n.min(SUCCESS_WINDOW)]);
        self.report.success_last30 = success(&self.outcomes[n.saturating_sub(SUCCESS_WINDOW)..]);
    }

    fn status(&mut self) -> Status {
        self.sync_report();
        let stats = self.replay.stats();
        Status::Buffer {
            steps_received: self.report.steps_received,
            episodes: self.report.episodes,
            success_last30: self.report.success_last30,
            inserted: stats.inserted,
            stored: (stats.push_len + stats.grasp_len) as u64,
            capacity: 2 * self.replay.config().capacity as u64,
            relabelled: stats.relabelled,
            lost: self.report.lost(),
        }
    }

    fn save(&mut self, dir: &RunDir) -> Result<()> {
        self.report.snapshots += 1;
        self.sync_report();
        self.replay.save(&dir.snapshot())?;
        let state = SavedState {
            report: self.report.clone(),
            open: self
                .streams
                .iter()
                .map(|(k, (_, open))| (*k, open.iter().copied().collect()))
                .collect(),
            outcomes: self.outcomes.clone(),
        };
        write_json(&dir.buffer_counters(), &state)?;
        let mut curve = String::from("episode,goal_grasped,success_last30\n");
        for (i, &grasped) in self.outcomes.iter().enumerate() {
            let window = &self.outcomes[(i + 1).saturating_sub(SUCCESS_WINDOW)..=i];
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

/// Serves until the launcher says stop; then takes every step still in flight, snapshots and
/// returns its counters. With `resume`, starts from the run directory's snapshot.
pub fn run(
    transport: &dyn Transport,
    config: &RunConfig,
    dir: &RunDir,
    resume: bool,
    log: &RunLog,
    lifeline: &Lifeline,
) -> Result<BufferReport> {
    let mut role = BufferRole::new(config)?;
    if resume && dir.snapshot().exists() {
        role.restore(dir)?;
    }
    let mut ports = Ports::open(transport)?;
    // The first report says the buffer listens: the launcher starts actors only then.
    ports.status.send(&Message::Status(role.status()))?;
    let mut inflow = Inflow::new(config.actors);
    let mut last_status = Instant::now();
    loop {
        let stop = role.obey(&mut ports.control, &mut inflow, dir)?;
        let mut busy = inflow.take(&mut ports.steps, &mut role, log, stop)?;
        if stop || lifeline.lost() {
            break;
        }
        busy |= role.take_requests(&mut ports.requests)?;
        busy |= role.serve(&mut ports.batches)?;
        if last_status.elapsed() >= STATUS_EVERY {
            role.report_to(&mut ports.status, log)?;
            last_status = Instant::now();
        }
        if !busy {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    role.save(dir)?;
    role.report_to(&mut ports.status, log)?;
    Ok(role.report)
}

/// The buffer's ends of the run's topics.
struct Ports {
    steps: Inbox,
    requests: Inbox,
    control: Inbox,
    batches: Outbox,
    status: Outbox,
}

impl Ports {
    fn open(transport: &dyn Transport) -> Result<Self> {
        Ok(Self {
            steps: Inbox::open(transport, Topic::Steps)?,
            requests: Inbox::open(transport, Topic::Requests)?,
            control: Inbox::open(transport, Topic::Control)?,
            batches: Outbox::open(transport, Topic::Batches)?,
            status: Outbox::open(transport, Topic::Status)?,
        })
    }
}

/// How steps come in. Back-pressure: steps wait in the transport while the learner lags
/// behind, except when the actors are stopping (what they send must arrive). They are taken
/// in rounds, all that every actor has waiting, then let in as the rate limiter allows:
/// iceoryx2 hands out the first publisher's messages first, so taking one at a time would
/// let in only one actor's steps whenever the learner sets the pace.
struct Inflow {
    /// A round: what every actor can have waiting in the transport, and one more.
    round: usize,
    staged: VecDeque<Message>,
    /// The launcher told the actors to stop: let everything in.
    actors_stopped: bool,
}

impl Inflow {
    fn new(actors: u32) -> Self {
        let round = (Topic::Steps.buffer() + 1) * actors.max(1) as usize;
        Self {
            round,
            staged: VecDeque::with_capacity(round),
            actors_stopped: false,
        }
    }

    /// Takes in steps and episode ends while the rate limiter allows (all of them when
    /// stopping); whether any came.
    fn take(
        &mut self,
        steps: &mut Inbox,
        role: &mut BufferRole,
        log: &RunLog,
        stopping: bool,
    ) -> Result<bool> {
        let mut busy = false;
        while self.actors_stopped || stopping || role.replay.can_insert(1) {
            if self.staged.is_empty() {
                while self.staged.len() < self.round
                    && let Some(message) = steps.try_recv()?
                {
                    self.staged.push_back(message);
                }
            }
            match self.staged.pop_front() {
                Some(Message::Step(step)) => role.step(step)?,
                Some(Message::EpisodeEnd(end)) => {
                    log.json(BUFFER_EPISODE, &end)?;
                    role.episode_end(end)?;
                }
                Some(other) => bail!("the steps topic carried {other:?}"),
                None => break,
            }
            busy = true;
        }
        Ok(busy)
    }
}
