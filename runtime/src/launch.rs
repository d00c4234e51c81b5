//! `pushgrasp train`: makes the run directory, starts the buffer, then the learner, then the
//! actors; shows progress; and stops everything in order (actors, then the learner, which
//! checkpoints, then the buffer, which takes the last steps and snapshots) when the budget
//! is reached, on Ctrl-C, or when a role fails more often than it is restarted.

mod names;
mod reports;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use bridge::Endpoint;
use clap::Args;
use mcaplog::LogLevel;
use wire::{ChannelTransport, Control, Inbox, Message, Outbox, Role, Topic, Transport};

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
use rundir::{Summary, write_json};

pub(crate) use names::open_launch;
use names::{default_run_id, newest_run};
use reports::{actor_reports, lost_in_fault, print_summary, report_or, unreceived_steps};

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
