//! The launcher: makes the run directory, starts the buffer, then the learner, then the
//! actors; shows progress; restarts a crashed actor; and stops everything in order (actors,
//! then the learner, which checkpoints, then the buffer, which takes the last steps and
//! snapshots) when the budget is reached, on Ctrl-C, or when the learner or the buffer fails.

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use mcaplog::{LogLevel, RunLog};
use serde::{Deserialize, Serialize};
use wire::{ChannelTransport, Control, Inbox, Message, Outbox, Role, Status, Topic, Transport};

use super::actor::{ActorId, ActorReport};
use super::buffer::BufferReport;
use super::config::RunConfig;
use super::learner::LearnerReport;
use super::record::{LAUNCHER_PROGRESS, LAUNCHER_SUMMARY};
use super::{Lifeline, read_json, write_json};

/// Crashes of one actor index the launcher restarts before it gives up on the run.
const MAX_RESTARTS: u32 = 10;
/// How long a role may take to stop once told to.
const STOP_TIMEOUT: Duration = Duration::from_secs(120);
/// How long the buffer may take to start listening.
const START_TIMEOUT: Duration = Duration::from_secs(60);

#[derive(Args)]
pub struct TrainArgs {
    /// The run's config (TOML); with --resume, the run directory's own copy is used.
    #[arg(long, default_value = "configs/stage1.toml")]
    config: PathBuf,
    /// Actor processes (default: the config's `actors`).
    #[arg(long)]
    actors: Option<u32>,
    /// Continue a run from its checkpoint and buffer snapshot (the newest run in --logs, or
    /// --run-id).
    #[arg(long)]
    resume: bool,
    /// The run's id and directory name under --logs (default: stage<N>-<unix time>).
    #[arg(long)]
    run_id: Option<String>,
    /// Override the episode budget (the run's total, resumed episodes included).
    #[arg(long)]
    episodes: Option<u64>,
    /// Override the learner-update budget.
    #[arg(long)]
    updates: Option<u64>,
    /// Start both nets from this checkpoint (an earlier stage's `checkpoint/`).
    #[arg(long)]
    init_from: Option<PathBuf>,
    /// Run the roles as threads of this process over channels instead of processes over
    /// shared memory.
    #[arg(long)]
    threads: bool,
    /// Where run directories go.
    #[arg(long, default_value = "logs")]
    logs: PathBuf,
}

/// One role of the run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RoleSpec {
    Buffer,
    Learner,
    Actor(ActorId),
}

impl RoleSpec {
    /// The role's name in logs, reports and shared-memory nodes.
    pub fn name(self) -> String {
        match self {
            RoleSpec::Buffer => "buffer".into(),
            RoleSpec::Learner => "learner".into(),
            RoleSpec::Actor(id) => format!("actor-{}-{}", id.index, id.incarnation),
        }
    }

    fn role(self) -> Role {
        match self {
            RoleSpec::Buffer => Role::Buffer,
            RoleSpec::Learner => Role::Learner,
            RoleSpec::Actor(_) => Role::Actor,
        }
    }
}

/// Runs a role to its end and writes its report to `<dir>/reports/<name>.json`; a failure
/// is also announced on the status topic, so the launcher can say why.
pub fn run_role(
    transport: &dyn Transport,
    spec: RoleSpec,
    config: &RunConfig,
    dir: &Path,
    resume: bool,
    lifeline: &Lifeline,
) -> Result<()> {
    let reports = dir.join("reports");
    std::fs::create_dir_all(&reports)?;
    let path = reports.join(format!("{}.json", spec.name()));
    let log = open_log(dir, &spec.name(), config)?;
    log.log_line(LogLevel::Info, &format!("{} started", spec.name()))?;
    let result = match spec {
        RoleSpec::Buffer => super::buffer::run(transport, config, dir, resume, &log, lifeline)
            .and_then(|r| write_json(&path, &r)),
        RoleSpec::Learner => super::learner::run(transport, config, dir, resume, &log, lifeline)
            .and_then(|r| write_json(&path, &r)),
        RoleSpec::Actor(id) => super::actor::run(transport, config, id, &log, lifeline)
            .and_then(|r| write_json(&path, &r)),
    };
    match &result {
        Ok(()) => log.log_line(LogLevel::Info, &format!("{} stopped", spec.name()))?,
        Err(e) => log.log_line(LogLevel::Fatal, &format!("{} failed: {e:#}", spec.name()))?,
    }
    log.finish()?;
    if let Err(e) = &result {
        let failed = Status::Failed {
            role: spec.role(),
            error: format!("{e:#}"),
        };
        if let Ok(mut status) = Outbox::open(transport, Topic::Status) {
            let _ = status.send(&Message::Status(failed));
        }
    }
    result
}

/// A process's MCAP log in the run directory, opened with the run's resolved config.
fn open_log(dir: &Path, name: &str, config: &RunConfig) -> Result<RunLog> {
    if !config.logging.enabled {
        return Ok(RunLog::disabled(name));
    }
    let log = RunLog::create(dir.join(format!("{name}.mcap")), name)?;
    let config = BTreeMap::from([("toml".to_string(), toml::to_string(config)?)]);
    log.metadata("config", &config)?;
    Ok(log)
}

/// A running role: a child process, or a thread of this one.
enum Worker {
    Process(Child),
    Thread(Option<JoinHandle<Result<()>>>),
}

impl Worker {
    /// `None` while it runs; then `Ok` for a clean exit or why it did not exit cleanly.
    fn finished(&mut self) -> Option<Result<(), String>> {
        match self {
            Worker::Process(child) => match child.try_wait() {
                Ok(None) => None,
                Ok(Some(status)) if status.success() => Some(Ok(())),
                Ok(Some(status)) => Some(Err(format!("exited with {status}"))),
                Err(e) => Some(Err(format!("cannot be waited for: {e}"))),
            },
            // Joined once, when it finished; the slot is done after that.
            Worker::Thread(handle) => handle.take_if(|h| h.is_finished()).map(|h| match h.join() {
                Ok(Ok(())) => Ok(()),
                Ok(Err(e)) => Err(format!("{e:#}")),
                Err(_) => Err("panicked".into()),
            }),
        }
    }

    fn kill(&mut self) {
        if let Worker::Process(child) = self {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    fn pid(&self) -> Option<u32> {
        match self {
            Worker::Process(child) => Some(child.id()),
            Worker::Thread(_) => None,
        }
    }
}

/// How the launcher starts roles.
enum Wiring {
    Processes { namespace: String },
    Threads { transport: ChannelTransport },
}

struct Slot {
    spec: RoleSpec,
    worker: Worker,
    /// Set once it exited (cleanly or not) and was dealt with.
    done: bool,
}

/// The processes file: which process plays which role (for users and tests).
#[derive(Serialize, Deserialize)]
pub struct ProcessEntry {
    pub role: String,
    pub pid: u32,
}

struct Launcher {
    wiring: Wiring,
    config: RunConfig,
    dir: PathBuf,
    resume: bool,
    slots: Vec<Slot>,
    log: RunLog,
    /// Restarts per actor index.
    crashes: BTreeMap<u32, u32>,
}

impl Launcher {
    fn start(&mut self, spec: RoleSpec) -> Result<()> {
        let worker = match &self.wiring {
            Wiring::Processes { namespace } => {
                let mut command = Command::new(std::env::current_exe()?);
                command
                    .arg("role")
                    .arg(match spec {
                        RoleSpec::Buffer => "buffer",
                        RoleSpec::Learner => "learner",
                        RoleSpec::Actor(_) => "actor",
                    })
                    .arg("--run-dir")
                    .arg(&self.dir)
                    .args(["--shm-namespace", namespace]);
                if self.resume {
                    command.arg("--resume");
                }
                if let RoleSpec::Actor(id) = spec {
                    command
                        .args(["--index", &id.index.to_string()])
                        .args(["--incarnation", &id.incarnation.to_string()]);
                }
                let log = self.dir.join(format!("{}.log", spec.name()));
                let log = std::fs::File::create(&log)
                    .with_context(|| format!("creating {}", log.display()))?;
                command
                    .stdin(Stdio::null())
                    .stdout(log.try_clone()?)
                    .stderr(log);
                Worker::Process(
                    command
                        .spawn()
                        .with_context(|| format!("starting the {}", spec.name()))?,
                )
            }
            Wiring::Threads { transport } => {
                let (transport, config, dir, resume) = (
                    transport.clone(),
                    self.config.clone(),
                    self.dir.clone(),
                    self.resume,
                );
                let handle = std::thread::Builder::new()
                    .name(spec.name())
                    .spawn(move || {
                        run_role(&transport, spec, &config, &dir, resume, &Lifeline::thread())
                    })?;
                Worker::Thread(Some(handle))
            }
        };
        self.log
            .log_line(LogLevel::Info, &format!("started the {}", spec.name()))?;
        self.slots.push(Slot {
            spec,
            worker,
            done: false,
        });
        self.write_processes()
    }

    /// The next incarnation of each actor index a resumed run starts: one past any that ran
    /// before (its report or log names it), so the buffer tells their streams apart.
    fn next_incarnations(&self) -> Result<BTreeMap<u32, u32>> {
        let mut next = BTreeMap::new();
        for dir in [self.dir.clone(), self.dir.join("reports")] {
            for entry in std::fs::read_dir(&dir)? {
                let name = entry?.file_name().to_string_lossy().into_owned();
                let Some(stem) = name
                    .strip_prefix("actor-")
                    .and_then(|n| n.split('.').next())
                else {
                    continue;
                };
                if let Some((index, incarnation)) = stem.split_once('-')
                    && let (Ok(index), Ok(incarnation)) =
                        (index.parse(), incarnation.parse::<u32>())
                {
                    let slot = next.entry(index).or_insert(0);
                    *slot = (*slot).max(incarnation + 1);
                }
            }
        }
        Ok(next)
    }

    fn write_processes(&self) -> Result<()> {
        let entries: Vec<ProcessEntry> = self
            .slots
            .iter()
            .filter(|s| !s.done)
            .filter_map(|s| {
                s.worker.pid().map(|pid| ProcessEntry {
                    role: s.spec.name(),
                    pid,
                })
            })
            .collect();
        write_json(&self.dir.join("processes.json"), &entries)
    }

    /// Deals with roles that exited: restarts a crashed actor; an exited learner or buffer
    /// ends the run with its reason.
    fn check(&mut self, failures: &[String]) -> Result<()> {
        let mut restart = Vec::new();
        for slot in self.slots.iter_mut().filter(|s| !s.done) {
            let Some(outcome) = slot.worker.finished() else {
                continue;
            };
            slot.done = true;
            match slot.spec {
                RoleSpec::Actor(id) => {
                    let why = outcome.err().unwrap_or_else(|| "stopped by itself".into());
                    let message = format!("{} {why}; starting it again", slot.spec.name());
                    eprintln!("{message}");
                    self.log.log_line(LogLevel::Warning, &message)?;
                    restart.push(ActorId {
                        index: id.index,
                        incarnation: id.incarnation + 1,
                    });
                }
                spec => {
                    let log = self.dir.join(format!("{}.log", spec.name()));
                    let why = failures
                        .iter()
                        .find(|f| f.starts_with(&spec.name()))
                        .cloned()
                        .or_else(|| last_error(&log))
                        .or_else(|| outcome.err())
                        .unwrap_or_else(|| "exited before it was told to".into());
                    bail!(
                        "the {} cannot continue: {why} (see {})",
                        spec.name(),
                        log.display()
                    );
                }
            }
        }
        for id in restart {
            let crashes = self.crashes.entry(id.index).or_insert(0);
            *crashes += 1;
            if *crashes > MAX_RESTARTS {
                bail!("actor {} crashed {crashes} times; giving up", id.index);
            }
            self.start(RoleSpec::Actor(id))?;
        }
        Ok(())
    }

    /// Tells one kind of role to stop and waits for every one of them; kills what does not
    /// stop in time.
    fn stop(&mut self, role: Role, control: &mut Outbox) -> Result<Vec<String>> {
        control.send(&Message::Control(Control::Stop(role)))?;
        let deadline = Instant::now() + STOP_TIMEOUT;
        let mut problems = Vec::new();
        for slot in self
            .slots
            .iter_mut()
            .filter(|s| !s.done && s.spec.role() == role)
        {
            let outcome = loop {
                if let Some(outcome) = slot.worker.finished() {
                    break outcome;
                }
                if Instant::now() > deadline {
                    slot.worker.kill();
                    break Err(format!(
                        "did not stop within {STOP_TIMEOUT:?} and was killed"
                    ));
                }
                std::thread::sleep(Duration::from_millis(20));
            };
            slot.done = true;
            if let Err(why) = outcome {
                problems.push(format!("{} {why}", slot.spec.name()));
            }
        }
        self.write_processes()?;
        Ok(problems)
    }

    /// Actor restarts so far.
    fn restarts(&self) -> u32 {
        self.crashes.values().sum()
    }

    fn kill_all(&mut self) {
        for slot in self.slots.iter_mut().filter(|s| !s.done) {
            slot.worker.kill();
            slot.done = true;
        }
    }
}

/// What the launcher saw of the run, from the roles' status reports.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Progress {
    pub episodes: u64,
    pub steps_received: u64,
    pub success_last30: Option<f64>,
    pub stored: u64,
    pub capacity: u64,
    pub relabelled: u64,
    pub lost: u64,
    pub updates: u64,
    pub weights_version: u64,
    pub loss: Option<f32>,
}

impl Progress {
    /// Takes a report in; a failure report is returned as text.
    fn take(&mut self, status: Status) -> Option<String> {
        match status {
            Status::Buffer {
                steps_received,
                episodes,
                success_last30,
                stored,
                capacity,
                relabelled,
                lost,
                ..
            } => {
                self.steps_received = steps_received;
                self.episodes = episodes;
                self.success_last30 = success_last30;
                self.stored = stored;
                self.capacity = capacity;
                self.relabelled = relabelled;
                self.lost = lost;
            }
            Status::Learner {
                updates,
                weights_version,
                loss,
            } => {
                self.updates = updates;
                self.weights_version = weights_version;
                self.loss = loss;
            }
            Status::Actor { .. } => {}
            Status::Failed { role, error } => {
                return Some(format!("{}: {error}", format!("{role:?}").to_lowercase()));
            }
        }
        None
    }

    fn line(&self, updates_per_s: f64) -> String {
        format!(
            "goal grasp success (last 30) {} | {updates_per_s:.1} updates/s | buffer {}/{} | weights v{}",
            percent(self.success_last30),
            self.stored,
            self.capacity,
            self.weights_version
        )
    }
}

/// What a finished run says about itself (`<run>/summary.json`).
#[derive(Debug, Serialize, Deserialize)]
pub struct Summary {
    pub run_id: String,
    pub actors: u32,
    pub restarts: u32,
    pub interrupted: bool,
    pub wall_s: f64,
    pub buffer: BufferReport,
    pub learner: LearnerReport,
    /// The reports of actors that stopped cleanly (a killed one writes none; its steps are
    /// accounted for by the buffer's per-incarnation counts).
    pub actors_reports: Vec<ActorReport>,
}

impl Summary {
    /// The `summary.json` of `run_dir`, if the run wrote one.
    pub fn read(run_dir: &Path) -> Result<Option<Summary>> {
        let path = run_dir.join("summary.json");
        if !path.exists() {
            return Ok(None);
        }
        read_json(&path).map(Some)
    }
}

fn default_run_id(stage: u8) -> String {
    let secs = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    format!("stage{stage}-{secs}")
}

/// The newest run directory under `logs` (the one `--resume` continues by default).
fn newest_run(logs: &Path) -> Result<String> {
    let mut runs: Vec<(SystemTime, String)> = std::fs::read_dir(logs)
        .with_context(|| format!("reading {}", logs.display()))?
        .filter_map(|e| e.ok())
        .filter(|e| e.path().join("config.toml").exists())
        .filter_map(|e| {
            let modified = e.metadata().and_then(|m| m.modified()).ok()?;
            Some((modified, e.file_name().to_string_lossy().into_owned()))
        })
        .collect();
    runs.sort();
    runs.pop()
        .map(|(_, id)| id)
        .ok_or_else(|| anyhow!("--resume: no run directory in {}", logs.display()))
}

/// A share as a whole percentage, or "-" when there is none yet.
pub fn percent(share: Option<f64>) -> String {
    share.map_or("-".into(), |s| format!("{:.0}%", 100.0 * s))
}

/// The error a failed role process printed last (its log's last "Error:" paragraph).
fn last_error(log: &Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    let start = text.rfind("Error: ")?;
    let error = text[start + "Error: ".len()..].trim();
    // anyhow's backtrace, if any, follows a blank line.
    Some(
        error
            .split("\n\n")
            .next()
            .unwrap_or(error)
            .replace('\n', " "),
    )
}

/// The name a run's shared-memory services go under: its id (what a person reading
/// `/dev/shm` recognises) and a hash of its directory, so that runs of one id in different
/// log directories (two pipelines' `stage1`) never see each other's messages.
fn shm_namespace(run_id: &str, dir: &Path) -> Result<String> {
    use std::hash::Hasher;
    let dir = std::fs::canonicalize(dir).with_context(|| format!("{}", dir.display()))?;
    let mut hasher = fnv::FnvHasher::default();
    hasher.write(dir.as_os_str().as_encoded_bytes());
    let hash = format!("{:016x}", hasher.finish());
    // Within the transport's limit on run ids, the hash and its dash kept whole.
    let id: String = run_id
        .chars()
        .take(wire::MAX_RUN_ID - hash.len() - 1)
        .collect();
    Ok(format!("{id}-{hash}"))
}

pub fn train(args: &TrainArgs) -> Result<()> {
    let run_id = match (&args.run_id, args.resume) {
        (Some(id), _) => id.clone(),
        (None, true) => newest_run(&args.logs)?,
        (None, false) => default_run_id(RunConfig::load(&args.config)?.stage),
    };
    let dir = args.logs.join(&run_id);
    let mut config = if args.resume {
        RunConfig::load(&dir.join("config.toml"))?
    } else {
        if dir.join("config.toml").exists() {
            bail!(
                "{} already holds a run: continue it with --resume, or pick another --run-id",
                dir.display()
            );
        }
        RunConfig::load(&args.config)?
    };
    if let Some(actors) = args.actors {
        config.actors = actors;
    }
    if let Some(episodes) = args.episodes {
        config.episodes = episodes;
    }
    if let Some(updates) = args.updates {
        config.updates = updates;
    }
    if let Some(init) = &args.init_from {
        // Absolute: the roles read it from the run directory's copy of the config.
        let init = std::fs::canonicalize(init)
            .with_context(|| format!("--init-from {}", init.display()))?;
        config.init_from = Some(init);
    }
    config.validate()?;
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    std::fs::write(dir.join("config.toml"), toml::to_string(&config)?)?;
    let reports = dir.join("reports");
    std::fs::create_dir_all(&reports)?;

    use signal_hook::consts::{SIGINT, SIGTERM, SIGUSR1};
    let interrupted = Arc::new(AtomicBool::new(false));
    for signal in [SIGINT, SIGTERM] {
        signal_hook::flag::register(signal, interrupted.clone())
            .context("installing the Ctrl-C handler")?;
    }
    // `kill -USR1 <launcher>` asks the buffer for a snapshot.
    let snapshot = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(SIGUSR1, snapshot.clone())
        .context("installing the SIGUSR1 handler")?;

    let (wiring, transport): (Wiring, Box<dyn Transport>) = if args.threads {
        let transport = ChannelTransport::new();
        (
            Wiring::Threads {
                transport: transport.clone(),
            },
            Box::new(transport),
        )
    } else {
        let namespace = shm_namespace(&run_id, &dir)?;
        wire::ShmTransport::remove_stale(&namespace)?;
        (
            Wiring::Processes {
                namespace: namespace.clone(),
            },
            Box::new(wire::ShmTransport::new(&namespace, "launcher")?),
        )
    };
    let mut status = Inbox::open(transport.as_ref(), Topic::Status)?;
    let mut control = Outbox::open(transport.as_ref(), Topic::Control)?;
    let mut launcher = Launcher {
        wiring,
        config: config.clone(),
        dir: dir.clone(),
        resume: args.resume,
        slots: Vec::new(),
        log: open_log(&dir, "launcher", &config)?,
        crashes: BTreeMap::new(),
    };
    println!(
        "run {run_id}: stage {}, {} actors ({}), logs in {}",
        config.stage,
        config.actors,
        if args.threads {
            "threads over channels"
        } else {
            "processes over shared memory"
        },
        dir.display()
    );
    let start = Instant::now();
    let signals = Signals {
        interrupted: &interrupted,
        snapshot: &snapshot,
    };
    let outcome = supervise(&mut launcher, &mut status, &mut control, &signals, start);
    if let Err(e) = outcome {
        let _ = launcher.log.log_line(LogLevel::Fatal, &format!("{e:#}"));
        // Stop what still runs, in order, so the checkpoint and snapshot are written if
        // their roles are alive; then report the failure.
        for role in [Role::Actor, Role::Learner, Role::Buffer] {
            let _ = launcher.stop(role, &mut control);
        }
        launcher.kill_all();
        return Err(e);
    }
    let interrupted = interrupted.load(Ordering::SeqCst);
    let mut actors_reports = Vec::new();
    for entry in std::fs::read_dir(&reports)? {
        let path = entry?.path();
        if path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with("actor-"))
        {
            actors_reports.push(read_json::<ActorReport>(&path)?);
        }
    }
    actors_reports.sort_by_key(|r| (r.actor, r.incarnation));
    let summary = Summary {
        run_id,
        actors: config.actors,
        restarts: launcher.restarts(),
        interrupted,
        wall_s: start.elapsed().as_secs_f64(),
        buffer: read_json(&reports.join("buffer.json"))?,
        learner: read_json(&reports.join("learner.json"))?,
        actors_reports,
    };
    write_json(&dir.join("summary.json"), &summary)?;
    launcher.log.json(LAUNCHER_SUMMARY, &summary)?;
    launcher.log.finish()?;
    println!(
        "{}: {} episodes, goal grasp success first 30 {}, last 30 {}, {} steps received ({} lost), {} learner updates, {} actor restarts, {:.1} s; checkpoint, buffer snapshot and curve.csv in {}",
        if interrupted { "interrupted" } else { "done" },
        summary.buffer.episodes,
        percent(summary.buffer.success_first30),
        percent(summary.buffer.success_last30),
        summary.buffer.steps_received,
        summary.buffer.lost(),
        summary.learner.updates,
        summary.restarts,
        summary.wall_s,
        dir.display()
    );
    if summary.buffer.lost() > 0 {
        bail!(
            "{} messages from the actors never arrived",
            summary.buffer.lost()
        );
    }
    Ok(())
}

/// What the launcher's signal handlers raised.
struct Signals<'a> {
    /// Ctrl-C or SIGTERM: stop the run.
    interrupted: &'a AtomicBool,
    /// SIGUSR1: the buffer snapshots now.
    snapshot: &'a AtomicBool,
}

/// Starts the roles, follows the run until its budget or an interrupt, then stops it in
/// order. Errors when a role that cannot be restarted fails.
fn supervise(
    launcher: &mut Launcher,
    status: &mut Inbox,
    control: &mut Outbox,
    signals: &Signals,
    start: Instant,
) -> Result<()> {
    let config = launcher.config.clone();
    let mut progress = Progress::default();
    let mut failures = Vec::new();
    let take = |status: &mut Inbox, progress: &mut Progress| -> Result<Vec<String>> {
        Ok(status
            .drain()?
            .into_iter()
            .filter_map(|m| match m {
                Message::Status(s) => progress.take(s),
                _ => None,
            })
            .collect())
    };

    // The buffer first: actors start only once it listens, so no step goes unheard.
    launcher.start(RoleSpec::Buffer)?;
    let deadline = Instant::now() + START_TIMEOUT;
    while progress.capacity == 0 {
        failures.extend(take(status, &mut progress)?);
        launcher.check(&failures)?;
        if Instant::now() > deadline {
            bail!("the buffer did not start within {START_TIMEOUT:?}");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    launcher.start(RoleSpec::Learner)?;
    let incarnations = launcher.next_incarnations()?;
    for index in 0..config.actors {
        launcher.start(RoleSpec::Actor(ActorId {
            index,
            incarnation: incarnations.get(&index).copied().unwrap_or(0),
        }))?;
    }

    let bar = if std::io::stderr().is_terminal() {
        let bar = ProgressBar::new(config.episodes);
        bar.set_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] {pos}/{len} episodes | {msg}",
            )
            .expect("a valid template")
            .progress_chars("=> "),
        );
        Some(bar)
    } else {
        None
    };
    let (mut last_print, mut last_updates, mut last_rate_at) =
        (Instant::now(), progress.updates, Instant::now());
    let mut updates_per_s = 0.0;
    let mut last_logged = Instant::now();
    loop {
        failures.extend(take(status, &mut progress)?);
        launcher.check(&failures)?;
        if signals.snapshot.swap(false, Ordering::SeqCst) {
            control.send(&Message::Control(Control::Snapshot))?;
        }
        // A restarted actor gets the newest order at once.
        control.refresh()?;
        if last_rate_at.elapsed() >= Duration::from_secs(2) {
            updates_per_s = (progress.updates - last_updates.min(progress.updates)) as f64
                / last_rate_at.elapsed().as_secs_f64();
            last_updates = progress.updates;
            last_rate_at = Instant::now();
        }
        if last_logged.elapsed() >= Duration::from_secs(1) {
            launcher.log.json(LAUNCHER_PROGRESS, &progress)?;
            last_logged = Instant::now();
        }
        let line = progress.line(updates_per_s);
        match &bar {
            Some(bar) => {
                bar.set_position(progress.episodes);
                bar.set_message(format!("{line} | restarts {}", launcher.restarts()));
            }
            None if last_print.elapsed() >= Duration::from_secs(10) => {
                println!(
                    "{:7.1} s  episodes {}/{}  {line}",
                    start.elapsed().as_secs_f64(),
                    progress.episodes,
                    config.episodes
                );
                last_print = Instant::now();
            }
            None => {}
        }
        let budget_spent = (config.episodes > 0 && progress.episodes >= config.episodes)
            || (config.updates > 0 && progress.updates >= config.updates);
        if budget_spent || signals.interrupted.load(Ordering::SeqCst) {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    if let Some(bar) = bar {
        bar.finish();
    }
    // Actors first (the buffer takes all they sent), then the learner (its checkpoint),
    // then the buffer (its snapshot).
    let mut problems = Vec::new();
    for role in [Role::Actor, Role::Learner, Role::Buffer] {
        problems.extend(launcher.stop(role, control)?);
    }
    let failed: Vec<&String> = problems
        .iter()
        .filter(|p| !p.starts_with("actor"))
        .collect();
    if !failed.is_empty() {
        bail!("stopping the run: {failed:?}");
    }
    for problem in problems {
        eprintln!("while stopping: {problem}");
    }
    Ok(())
}
