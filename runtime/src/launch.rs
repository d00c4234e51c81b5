//! `pushgrasp train`: makes the run directory, starts the buffer, then the learner, then the
//! actors; shows progress; and stops everything in order (actors, then the learner, which
//! checkpoints, then the buffer, which takes the last steps and snapshots) when the budget
//! is reached, on Ctrl-C, or when a role fails more often than it is restarted.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result, anyhow, bail};
use bridge::Endpoint;
use clap::Args;
use mcaplog::LogLevel;
use wire::{ChannelTransport, Control, Inbox, Message, Outbox, Role, ShmLimits, Topic, Transport};

use crate::actor::ActorId;
use crate::hosts::HostLink;
use crate::machine::{Allowance, Demand};
use crate::process_log::open_log;
use crate::progress::{Display, Watch};
use crate::role::RoleId;
use crate::signals::Signals;
use crate::supervisor::{RESUME_HINT, Supervisor, Wiring};
use rundir::backend::{self, Backend};
use rundir::config::RunConfig;
use rundir::record::LAUNCHER_SUMMARY;
use rundir::run_dir::RunDir;
use rundir::settings::{load_with, merge, parse_setting};
use rundir::{ActorReport, BufferReport, LearnerReport, Summary, percent, read_json, write_json};

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
    /// Let actors on other hosts join (`pushgrasp join`) at this endpoint,
    /// `tcp/<address>:<port>`; they present the secret written to `<run>/run.secret`.
    #[arg(long)]
    listen: Option<Endpoint>,
    /// Actors expected on joined hosts (the config's `run.remote_actors`): Ape-X's exploration
    /// rates spread over these and the local ones; with it, `--actors 0` is allowed.
    #[arg(long)]
    remote_actors: Option<u32>,
    /// The backend of the learner's and the actors' nets, `cpu` or `wgpu` (the config's
    /// `[backend]`; one of them alone: `--set backend.learner='"wgpu"'`).
    #[arg(long)]
    backend: Option<Backend>,
    /// A setting that replaces the config's (with --resume, the run's own): a dotted key and
    /// a TOML value, e.g. `--set learning.gamma=0.9`. Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = parse_setting)]
    set: Vec<toml::Table>,
}

pub fn train(args: &TrainArgs) -> Result<()> {
    let (run_id, dir, config, demand) = prepare_run(args)?;
    let signals = Signals::install()?;
    let (wiring, transport) = wiring(args.threads, &run_id, &dir, &demand)?;
    let mut link = HostLink::new(args.listen.as_ref(), &run_id, &dir, &config, &transport)?;
    let mut status = Inbox::open(transport.as_ref(), Topic::Status)?;
    let mut control = Outbox::open(transport.as_ref(), Topic::Control)?;
    let log = open_log(&dir, "launcher", &config)?;
    let mut supervisor = Supervisor::new(wiring, config.clone(), dir.clone(), args.resume, log);
    let how = if args.threads {
        "threads over channels".to_string()
    } else {
        format!("processes over shared memory: {}", demand.describe())
    };
    let environments = match config.envs_per_actor {
        1 => String::new(),
        k => format!(" x {k} environments"),
    };
    println!(
        "run {run_id}: stage {}, {} actors{environments} ({how}), logs in {}",
        config.stage,
        config.actors,
        dir.path().display()
    );
    let start = Instant::now();
    let mut watch = Watch::default();
    let outcome = supervise(
        &mut supervisor,
        &mut watch,
        &mut status,
        &mut control,
        &signals,
        &mut link,
    );
    if let Err(e) = &outcome {
        let _ = supervisor.log.log_line(LogLevel::Fatal, &format!("{e:#}"));
        // Stop what still runs, in order, so the checkpoint and snapshot are written if
        // their roles are alive; then report the failure.
        for role in [Role::Actor, Role::Learner, Role::Buffer] {
            let _ = supervisor.stop(role, &mut control);
        }
        supervisor.kill_all();
    }
    let hosts = link.close().unwrap_or_else(|e| {
        eprintln!("closing the link to the joined hosts: {e:#}");
        Vec::new()
    });
    // A role that died wrote no report: its last status report's counts stand in.
    let buffer = report_or(&dir.report(&supervisor.buffer().name()), || {
        watch.progress.buffer_report()
    })?;
    let actors_reports = actor_reports(&dir)?;
    let unreceived_steps = unreceived_steps(&supervisor, &buffer, &actors_reports);
    let mut summary = Summary {
        run_id,
        actors: config.actors,
        envs_per_actor: config.envs_per_actor,
        restarts: supervisor.restarts(),
        interrupted: signals.interrupted(),
        wall_s: start.elapsed().as_secs_f64(),
        buffer,
        learner: report_or(&dir.report(&supervisor.learner().name()), || {
            watch.progress.learner_report()
        })?,
        actors_reports,
        unreceived_steps,
        faults: supervisor.faults.clone(),
        failure: outcome.as_ref().err().map(|e| format!("{e:#}")),
        hosts,
    };
    for fault in &mut summary.faults {
        fault.lost_messages = lost_in_fault(&summary.buffer, &fault.role, &config);
    }
    write_json(&dir.summary(), &summary)?;
    supervisor.log.json(LAUNCHER_SUMMARY, &summary)?;
    supervisor.log.finish()?;
    print_summary(&summary, &dir);
    outcome?;
    if summary.lost() > 0 {
        bail!("{} messages from the actors never arrived", summary.lost());
    }
    Ok(())
}

/// The run's id, its directory, its config with the command line's overrides, checked and
/// written to the directory (or, with `--resume`, read from it), and what it asks of this
/// machine (checked).
fn prepare_run(args: &TrainArgs) -> Result<(String, RunDir, RunConfig, Demand)> {
    let run_id = match (&args.run_id, args.resume) {
        (Some(id), _) => id.clone(),
        (None, true) => newest_run(&args.logs)?,
        (None, false) => default_run_id(RunConfig::load(&args.config)?.stage),
    };
    let dir = RunDir::in_logs(&args.logs, &run_id);
    let path = if args.resume {
        dir.config()
    } else {
        if dir.holds_run() {
            bail!(
                "{} already holds a run: continue it with --resume, or pick another --run-id",
                dir.path().display()
            );
        }
        args.config.clone()
    };
    let mut set = args.backend.map(backend::setting).unwrap_or_default();
    for setting in &args.set {
        merge(&mut set, setting);
    }
    let (mut config, _) = load_with(&path, &set, "--set and --backend")?;
    if let Some(actors) = args.actors {
        config.actors = actors;
    }
    if let Some(episodes) = args.episodes {
        config.episodes = episodes;
    }
    if let Some(updates) = args.updates {
        config.updates = updates;
    }
    if let Some(remote_actors) = args.remote_actors {
        config.run.remote_actors = remote_actors;
    }
    if let Some(init) = &args.init_from {
        // Absolute: the roles read it from the run directory's copy of the config.
        let init = std::fs::canonicalize(init)
            .with_context(|| format!("--init-from {}", init.display()))?;
        config.init_from = Some(init);
    }
    config.validate()?;
    let replay = config.size_buffer()?;
    config.backend.check()?;
    let demand = Demand::new(&config, config.actors, CENTRAL_ROLES, replay)?;
    if !args.threads {
        demand.check(&Allowance::here())?;
    }
    std::fs::create_dir_all(dir.reports())
        .with_context(|| format!("creating {}", dir.path().display()))?;
    dir.write_config(&toml::to_string(&config)?)?;
    Ok((run_id, dir, config, demand))
}

/// The processes of a run on the central host beside its actors: the launcher, the buffer
/// and the learner.
const CENTRAL_ROLES: u32 = 3;

/// A transport the bridge's threads share with the launcher.
type Shared = Arc<dyn Transport + Send + Sync>;

/// How the roles meet: threads over channels, or processes over the run's shared memory
/// (what killed processes of earlier launches of this run left removed first).
fn wiring(threads: bool, run_id: &str, dir: &RunDir, demand: &Demand) -> Result<(Wiring, Shared)> {
    if threads {
        let transport = ChannelTransport::new();
        let wiring = Wiring::Threads {
            transport: transport.clone(),
        };
        return Ok((wiring, Arc::new(transport)));
    }
    let limits = demand.limits();
    let (namespace, transport) = open_launch(run_id, dir, "launcher", limits)?;
    Ok((Wiring::Processes { namespace, limits }, Arc::new(transport)))
}

/// The report at `path`, or `missing()` when the role wrote none (it died); a report that
/// cannot be read is an error naming it.
fn report_or<T: serde::de::DeserializeOwned>(path: &Path, missing: impl Fn() -> T) -> Result<T> {
    if path.exists() {
        read_json(path)
    } else {
        Ok(missing())
    }
}

/// What the buffer counted lost to the fault of role `role`: the gaps in the streams of a
/// crashed actor process's environments, or what the buffer that took over from a crashed
/// one found missing.
fn lost_in_fault(buffer: &BufferReport, role: &str, config: &RunConfig) -> Option<u64> {
    let streams: Vec<u64> = buffer
        .streams
        .iter()
        .filter(|s| {
            let process = ActorId {
                index: config.layout().process_of(s.actor),
                incarnation: s.incarnation,
            };
            RoleId::Actor(process).name() == role
        })
        .map(|s| s.missing)
        .collect();
    if !streams.is_empty() {
        return Some(streams.iter().sum());
    }
    buffer
        .restart_losses
        .iter()
        .find(|&(&next, _)| next > 0 && RoleId::Buffer(next - 1).name() == role)
        .map(|(_, &lost)| lost)
}

/// Steps that the actors this launch started, and stopped in order, sent and the buffer
/// never received ([`BufferReport::unreceived`]). Not those of a launch before, which may
/// have ended hung, its roles stopping by themselves in any order; none after a restart of
/// the buffer, which counts its losses apart.
fn unreceived_steps(supervisor: &Supervisor, buffer: &BufferReport, actors: &[ActorReport]) -> u64 {
    if supervisor.buffer() != RoleId::Buffer(0) {
        return 0;
    }
    let config = supervisor.config();
    let stopped_here: Vec<ActorReport> = actors
        .iter()
        .filter(|r| {
            supervisor.started_actor(ActorId {
                index: config.layout().process_of(r.actor),
                incarnation: r.incarnation,
            })
        })
        .cloned()
        .collect();
    buffer.unreceived(&stopped_here)
}

/// The reports of actors that stopped cleanly, in index and incarnation order.
fn actor_reports(dir: &RunDir) -> Result<Vec<ActorReport>> {
    let mut reports = Vec::new();
    for entry in std::fs::read_dir(dir.reports())? {
        let path = entry?.path();
        if path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with(Role::Actor.name()))
        {
            reports.push(read_json::<ActorReport>(&path)?);
        }
    }
    reports.sort_by_key(|r| (r.actor, r.incarnation));
    Ok(reports)
}

fn print_summary(summary: &Summary, dir: &RunDir) {
    println!(
        "{}: {} episodes, goal grasp success first 30 {}, last 30 {}, {} steps received ({} lost{}), {} learner updates{}, {} restarts, {:.1} s; checkpoint, buffer snapshot and curve.csv in {}",
        match (&summary.failure, summary.interrupted) {
            (Some(_), _) => "failed",
            (None, true) => "interrupted",
            (None, false) => "done",
        },
        summary.buffer.episodes,
        percent(summary.buffer.success_first30),
        percent(summary.buffer.success_last30),
        summary.buffer.steps_received,
        summary.lost(),
        match summary.buffer.lost_in_restarts {
            0 => String::new(),
            n => format!(", {n} messages lost to restarts of the buffer"),
        },
        summary.learner.updates,
        learner_pace(&summary.learner),
        summary.restarts,
        summary.wall_s,
        dir.path().display()
    );
    crate::hosts::print_hosts(&summary.hosts);
}

/// The learner's pace in a summary line: its updates a second, and how much of the time it
/// was updating (near all of it, the learner paced the run; else the actors did) with its
/// updates a second of that time.
fn learner_pace(learner: &LearnerReport) -> String {
    match (
        learner.updates_per_s(),
        learner.busy_share(),
        learner.updates_per_busy_s(),
    ) {
        (Some(rate), Some(share), Some(own)) => format!(
            " ({rate:.1}/s, busy {:.0}% of the time: {own:.1} a busy second)",
            100.0 * share
        ),
        _ => String::new(),
    }
}

/// Starts the roles, follows the run until its budget or an interrupt, then stops it in
/// order. Errors when a role that cannot be restarted fails.
fn supervise(
    supervisor: &mut Supervisor,
    watch: &mut Watch,
    status: &mut Inbox,
    control: &mut Outbox,
    signals: &Signals,
    link: &mut HostLink,
) -> Result<()> {
    let config = supervisor.config().clone();
    start_roles(supervisor, status, watch, config.actors)?;
    link.open()?;
    let mut display = Display::new(config.episodes, Instant::now());
    loop {
        watch.read(status, supervisor)?;
        link.check(supervisor)?;
        if signals.snapshot_asked() {
            control.send(&Message::Control(Control::Snapshot))?;
        }
        // A restarted actor gets the newest order at once.
        control.refresh()?;
        display.show(&watch.progress, supervisor)?;
        let progress = &watch.progress;
        let budget_spent = (config.episodes > 0 && progress.episodes >= config.episodes)
            || (config.updates > 0 && progress.updates >= config.updates);
        if budget_spent || signals.interrupted() {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    display.finish();
    stop_in_order(supervisor, control, link)
}

/// The buffer first (actors start only once it listens, so no step goes unheard), then the
/// learner, then the actors, each as the incarnation after any that ran before.
fn start_roles(
    supervisor: &mut Supervisor,
    status: &mut Inbox,
    watch: &mut Watch,
    actors: u32,
) -> Result<()> {
    supervisor.start(RoleId::Buffer(0))?;
    let deadline = Instant::now() + START_TIMEOUT;
    while watch.progress.capacity == 0 {
        watch.read(status, supervisor)?;
        if Instant::now() > deadline {
            bail!("the buffer did not start within {START_TIMEOUT:?}");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    supervisor.start(RoleId::Learner(0))?;
    let incarnations = supervisor.next_incarnations()?;
    for first in supervisor.config().layout().first_environments(0, actors) {
        supervisor.start(RoleId::Actor(ActorId {
            index: first,
            incarnation: incarnations.get(&first).copied().unwrap_or(0),
        }))?;
    }
    Ok(())
}

/// Actors first, local and joined hosts' (the buffer takes all they sent), then the learner
/// (its checkpoint), then the buffer (its snapshot). An actor that stopped badly is reported;
/// anything else fails.
fn stop_in_order(supervisor: &mut Supervisor, control: &mut Outbox, link: &HostLink) -> Result<()> {
    let mut problems = supervisor.stop(Role::Actor, control)?;
    link.wait_for_hosts(supervisor);
    for role in [Role::Learner, Role::Buffer] {
        problems.extend(supervisor.stop(role, control)?);
    }
    let failed: Vec<&String> = problems
        .iter()
        .filter(|p| !p.starts_with(Role::Actor.name()))
        .collect();
    if !failed.is_empty() {
        let failed: Vec<&str> = failed.iter().map(|p| p.as_str()).collect();
        bail!("stopping the run: {}; {RESUME_HINT}", failed.join("; "));
    }
    for problem in problems {
        eprintln!("while stopping: {problem}");
    }
    Ok(())
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
        .filter(|e| RunDir::new(e.path()).holds_run())
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

/// This launch's shared memory, as `node`: what the run's dead processes left removed, then a
/// transport under a namespace of this launch's own ([`launch_namespace`]) with the run's
/// limits, which it returns.
pub(crate) fn open_launch(
    run_id: &str,
    dir: &RunDir,
    node: &str,
    limits: ShmLimits,
) -> Result<(String, wire::ShmTransport)> {
    let run_space = shm_namespace(run_id, dir)?;
    wire::ShmTransport::remove_stale(&run_space)?;
    let namespace = launch_namespace(&run_space);
    let transport = wire::ShmTransport::new(&namespace, node, limits)?;
    Ok((namespace, transport))
}

/// The name a run's shared-memory services go under: its id (what a person reading
/// `/dev/shm` recognises) and a hash of its directory, so that runs of one id in different
/// log directories (two pipelines' `stage1`) never see each other's messages.
fn shm_namespace(run_id: &str, dir: &RunDir) -> Result<String> {
    use std::hash::Hasher;
    let dir =
        std::fs::canonicalize(dir.path()).with_context(|| format!("{}", dir.path().display()))?;
    let mut hasher = fnv::FnvHasher::default();
    hasher.write(dir.as_os_str().as_encoded_bytes());
    let hash = format!("{:016x}", hasher.finish());
    // Within the transport's limit on run ids, the hash and its dash kept whole, with room
    // for a launch's suffix.
    let id: String = run_id
        .chars()
        .take(wire::MAX_RUN_ID - hash.len() - 1 - LAUNCH_SUFFIX)
        .collect();
    Ok(format!("{id}-{hash}"))
}

/// Room [`launch_namespace`] takes after a run's namespace: `-` and a `u32` in hex.
const LAUNCH_SUFFIX: usize = 1 + 8;

/// The namespace of one launch of the run whose namespace is `run_space`: this launcher's
/// process id after it. Each launch meets its roles in services of its own: a launch killed
/// while it created one leaves it half made, and iceoryx2 refuses to open such a service
/// ("hangs in creation"), so a resumed run must not meet it.
fn launch_namespace(run_space: &str) -> String {
    format!("{run_space}-{:x}", std::process::id())
}
