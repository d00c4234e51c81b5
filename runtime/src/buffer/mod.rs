//! The buffer role: receives every actor's steps, assembles and relabels episodes into the
//! prioritised replay, answers the learner's sample requests and applies its priority
//! updates, and snapshots: every `[buffer] snapshot_every_s` in the background, on request
//! and at shutdown.
//!
//! Every message on the steps topic carries its sender's sequence number, so the buffer
//! proves the transport lost nothing: per actor incarnation, what arrived is exactly 0..n.
//! When an actor index comes back as a new incarnation (its process was restarted), the
//! episodes the old one left open are stored as they are.

mod state;

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use mcaplog::{LogLevel, RunLog};
use wire::{Inbox, Message, Outbox, Role, Topic, Transport};

use crate::{Lifeline, STATUS_EVERY};
use rundir::BufferReport;
use rundir::config::RunConfig;
use rundir::record::BUFFER_EPISODE;
use rundir::run_dir::{RunDir, previous};
use state::{BufferRole, Orders};

/// How this buffer process starts.
#[derive(Clone, Copy, Debug)]
pub struct Start {
    /// From the run directory's snapshot, if it holds one.
    pub resume: bool,
    /// 0, then one more for each restart of the buffer in the run.
    pub incarnation: u32,
}

/// Serves until the launcher says stop; then takes every step still in flight, snapshots and
/// returns its counters. With `resume`, starts from the run directory's snapshot.
pub fn run(
    transport: &dyn Transport,
    config: &RunConfig,
    dir: &RunDir,
    start: Start,
    log: &RunLog,
    lifeline: &Lifeline,
) -> Result<BufferReport> {
    let mut role = BufferRole::new(config, start.incarnation)?;
    let mut warning = None;
    if start.resume && (dir.snapshot().exists() || previous(&dir.snapshot()).exists()) {
        warning = role.restore(dir)?;
        let stats = role.replay.stats();
        let message = format!(
            "restored {} stored items and {} episodes from the snapshot",
            stats.push_len + stats.grasp_len,
            role.report.episodes
        );
        eprintln!("buffer: {message}");
        log.log_line(LogLevel::Info, &message)?;
    }
    let mut ports = Ports::open(transport, start.incarnation)?;
    if let Some(warning) = warning {
        crate::process_log::warn(&mut ports.status, log, Role::Buffer, warning)?;
    }
    // The first report says the buffer listens: the launcher starts actors only then.
    ports.status.send(&Message::Status(role.status()))?;
    let mut inflow = Inflow::new(config);
    let mut last_status = Instant::now();
    let snapshot_every = (config.buffer.snapshot_every_s > 0.0)
        .then(|| Duration::from_secs_f64(config.buffer.snapshot_every_s));
    let mut last_snapshot = Instant::now();
    loop {
        let Orders {
            stop,
            actors_stopped,
        } = role.obey(&mut ports.control, dir)?;
        inflow.actors_stopped |= actors_stopped;
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
        if snapshot_every.is_some_and(|every| last_snapshot.elapsed() >= every) {
            role.save_in_background(dir)?;
            last_snapshot = Instant::now();
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
    /// Opens the topics, then tells the learner that this buffer listens: what it asked a
    /// predecessor (a buffer that died) will never be answered, so it asks again. (Told
    /// before this buffer listened, it would ask into the void.)
    fn open(transport: &dyn Transport, incarnation: u32) -> Result<Self> {
        let mut ports = Self {
            steps: Inbox::open(transport, Topic::Steps)?,
            requests: Inbox::open(transport, Topic::Requests)?,
            control: Inbox::open(transport, Topic::Control)?,
            batches: Outbox::open(transport, Topic::Batches)?,
            status: Outbox::open(transport, Topic::Status)?,
        };
        ports.batches.send(&Message::BufferStarted(incarnation))?;
        Ok(ports)
    }
}

/// How steps come in. Back-pressure: steps wait in the transport while the learner lags
/// behind, except when the actors are stopping (what they send must arrive). They are taken
/// in rounds, all that every actor has waiting, then let in as the rate limiter allows:
/// iceoryx2 hands out the first publisher's messages first, so taking one at a time would
/// let in only one actor's steps whenever the learner sets the pace.
struct Inflow {
    /// A round: what every actor process can have waiting, and one more.
    round: usize,
    staged: VecDeque<Message>,
    /// The launcher told the actors to stop: let everything in.
    actors_stopped: bool,
}

impl Inflow {
    /// For the run's actor processes (here and on joined hosts).
    fn new(config: &RunConfig) -> Self {
        let k = config.envs_per_actor as usize;
        // What a process can have waiting: its buffer in the transport, and one action of
        // all its environments (a step and an episode end each, and each trial's) that it
        // sends as soon as there is room, while a round is read. With less, the processes
        // read first fill the round again and the last are never read.
        let waiting = Topic::Steps.buffer_for(k) + 2 * k * (1 + config.grasp_trials);
        let processes = (config.actors + config.run.remote_actors).max(1) as usize;
        let round = (waiting + 1) * processes;
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
        // Connect to actors that joined even while holding their steps back: what they
        // send is then kept for this buffer if they stop and exit before it reads them.
        steps.refresh()?;
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
