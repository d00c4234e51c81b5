//! `pushgrasp join`: a host's actors joining a run that listens on another machine
//! (`train --listen`). The host gets its actors' indices and the run's config from the
//! central host, runs its actors as processes over its own shared memory (supervised as the
//! launcher supervises them: a crashed or hung actor starts again), and one bridge that
//! carries their steps up and the weights down. It stops when the run stops its actors, on
//! Ctrl-C, or when the central host has been gone too long.
//!
//! Its files are a run directory of their own, `<logs>/<run id>/hosts/<host>/`: gathered
//! into the central run's directory (or written there, on a shared filesystem), `inspect`
//! reads them with the run's.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use bridge::host::UpReport;
use bridge::{Endpoint, HostBridge, JoinRequest, Keys, RunSecret};
use clap::Args;
use wire::{Inbox, Outbox, Role, Topic, Transport};

use crate::actor::ActorId;
use crate::launch::open_launch;
use crate::machine::{Allowance, Demand};
use crate::process_log::open_log;
use crate::progress::Watch;
use crate::role::RoleId;
use crate::signals::Signals;
use crate::supervisor::{Supervisor, Wiring};
use rundir::config::RunConfig;
use rundir::run_dir::RunDir;
use rundir::{HostSummary, write_json};

#[derive(Args)]
pub struct JoinArgs {
    /// Where the run listens: the endpoint given to its `train --listen`.
    pub endpoint: Endpoint,
    /// The run's id.
    #[arg(long)]
    pub run_id: String,
    /// The run's secret (`<run>/run.secret` on the central host, copied here or on a shared
    /// filesystem; readable by its owner alone).
    #[arg(long)]
    pub secret_file: PathBuf,
    /// Actor processes on this host.
    #[arg(long)]
    pub actors: u32,
    /// Where this host's run directory goes (`<logs>/<run id>/hosts/<host>/`).
    #[arg(long, default_value = "logs")]
    pub logs: PathBuf,
    /// This host's name in the run (default: the machine's); the same name joining again
    /// keeps its actor indices.
    #[arg(long)]
    pub host_name: Option<String>,
    /// Seconds the central host may be gone before this host stops its actors and exits.
    #[arg(long, default_value_t = 60.0)]
    pub give_up_after_s: f64,
}

/// Why the host stops.
enum End {
    /// The run stopped its actors.
    Ordered,
    Interrupted,
    CentralGone(Duration),
}

/// The central host's answer to this host's request: where it stands in the run.
struct Joined {
    host: String,
    session: bridge::zenoh::Session,
    keys: Keys,
    placement: bridge::Placement,
    config: RunConfig,
}

pub fn join(args: &JoinArgs) -> Result<()> {
    let Joined {
        host,
        session,
        keys,
        placement,
        config,
    } = ask_to_join(args)?;
    let dir = RunDir::in_logs(&args.logs, &args.run_id).host(&host);
    std::fs::create_dir_all(dir.reports())
        .with_context(|| format!("creating {}", dir.path().display()))?;
    dir.write_config(&placement.config)?;
    // This host's own shared memory: named after the run, this directory and this launch, as
    // a run's is (a host killed while it made a service rejoins under a namespace of its own).
    // This host's processes: its actors and the one that bridges them to the central host.
    let demand = Demand::new(&config, args.actors, 1, 0)?;
    demand.check(&Allowance::here())?;
    let limits = demand.limits();
    let (namespace, transport) = open_launch(&args.run_id, &dir, "bridge", limits)?;
    let transport: Arc<dyn Transport + Send + Sync> = Arc::new(transport);
    let bridge = HostBridge::start(session, keys, &host, transport.clone())?;
    let signals = Signals::install()?;
    let mut status = Inbox::open(transport.as_ref(), Topic::Status)?;
    let mut control = Outbox::open(transport.as_ref(), Topic::Control)?;
    let log = open_log(&dir, "host", &config)?;
    let mut supervisor = Supervisor::new(
        Wiring::Processes {
            namespace: namespace.clone(),
            limits,
        },
        config,
        dir.clone(),
        false,
        log,
    );
    let layout = supervisor.config().layout();
    let last = placement.first_actor + layout.environments(args.actors);
    println!(
        "joined run {} at {} as host {host}: actors {}..{last} ({}), logs in {}",
        args.run_id,
        args.endpoint,
        placement.first_actor,
        demand.describe(),
        dir.path().display()
    );
    for first in layout.first_environments(placement.first_actor, args.actors) {
        supervisor.start(RoleId::Actor(ActorId {
            index: first,
            incarnation: placement.incarnation,
        }))?;
    }
    let give_up = Duration::from_secs_f64(args.give_up_after_s.max(0.0));
    let mut watch = Watch::default();
    let outcome = follow(
        &mut supervisor,
        &mut watch,
        &mut status,
        &bridge,
        &signals,
        give_up,
    );
    let abandon = !matches!(outcome, Ok(End::Ordered | End::Interrupted))
        || bridge.central_gone_for() > Duration::ZERO;
    if abandon {
        // Nothing more can be delivered: the actors' queues drain so that they can stop.
        bridge.abandon();
    }
    let problems = supervisor.stop(Role::Actor, &mut control)?;
    for problem in &problems {
        eprintln!("while stopping: {problem}");
    }
    let sent = bridge.finish(give_up)?;
    let ended = why_it_ended(&outcome);
    let summary = summary(
        &args.run_id,
        &host,
        &placement,
        args.actors,
        &sent,
        &supervisor,
        &ended,
    );
    supervisor.log.finish()?;
    write_json(&dir.report("host"), &summary)?;
    print_stopped(&host, &ended, &sent);
    drop(status);
    drop(control);
    drop(transport);
    wire::ShmTransport::remove_stale(&namespace)?;
    match outcome? {
        End::CentralGone(_) => bail!("host {host}: {ended}; its actors were stopped"),
        End::Ordered | End::Interrupted => Ok(()),
    }
}

/// Checks the arguments, connects to the central host and asks it for this host's place.
fn ask_to_join(args: &JoinArgs) -> Result<Joined> {
    let secret = RunSecret::read(&args.secret_file)?;
    if secret.run_id != args.run_id {
        bail!(
            "{} holds the secret of run {:?}, not {:?}",
            args.secret_file.display(),
            secret.run_id,
            args.run_id
        );
    }
    if args.actors == 0 {
        bail!("--actors: a joined host runs at least 1 actor");
    }
    let host = match &args.host_name {
        Some(name) => name.clone(),
        None => machine_name()?,
    };
    bridge::traces::install(false);
    let session = bridge::session::connect(&args.endpoint, &args.run_id, &secret)?;
    let keys = Keys::new(&args.run_id);
    let request = JoinRequest {
        run_id: args.run_id.clone(),
        host: host.clone(),
        actors: args.actors,
    };
    let placement = bridge::host::join(&session, &keys, &request)?;
    let config = RunConfig::parse(&placement.config, "the run's config from the central host")?;
    Ok(Joined {
        host,
        session,
        keys,
        placement,
        config,
    })
}

/// The host's closing line: why it stopped and what its bridge sent.
fn print_stopped(host: &str, ended: &str, sent: &UpReport) {
    println!(
        "host {host} stopped ({ended}): {} steps and episode ends sent in {} parcels ({:.1}x compressed, {} sent again after the link dropped), {} thrown away",
        sent.messages,
        sent.parcels,
        sent.raw_bytes as f64 / sent.sent_bytes.max(1) as f64,
        sent.resent,
        sent.abandoned
    );
}

/// Why the host stopped, in its report's words.
fn why_it_ended(outcome: &Result<End>) -> String {
    match outcome {
        Ok(End::Ordered) => "the run stopped its actors".to_string(),
        Ok(End::Interrupted) => "interrupted".to_string(),
        Ok(End::CentralGone(gone)) => {
            format!("the central host was gone for {:.0} s", gone.as_secs_f64())
        }
        Err(e) => format!("{e:#}"),
    }
}

/// Supervises the actors until the run stops them, Ctrl-C, or the central host is gone.
fn follow(
    supervisor: &mut Supervisor,
    watch: &mut Watch,
    status: &mut Inbox,
    bridge: &HostBridge,
    signals: &Signals,
    give_up: Duration,
) -> Result<End> {
    let mut last_news = Instant::now();
    loop {
        watch.read(status, supervisor)?;
        if bridge.stop_ordered() {
            return Ok(End::Ordered);
        }
        if signals.interrupted() {
            return Ok(End::Interrupted);
        }
        let gone = bridge.central_gone_for();
        if gone > give_up {
            return Ok(End::CentralGone(gone));
        }
        if bridge.failed() {
            bail!("the bridge to the central host stopped");
        }
        if gone >= Duration::from_secs(1) && last_news.elapsed() > Duration::from_secs(5) {
            eprintln!(
                "the central host has been gone for {:.0} s (giving up after {:.0} s)",
                gone.as_secs_f64(),
                give_up.as_secs_f64()
            );
            last_news = Instant::now();
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn summary(
    run_id: &str,
    host: &str,
    placement: &bridge::Placement,
    actors: u32,
    sent: &UpReport,
    supervisor: &Supervisor,
    ended: &str,
) -> HostSummary {
    HostSummary {
        run_id: run_id.into(),
        host: host.into(),
        first_actor: placement.first_actor,
        actors,
        incarnation: placement.incarnation,
        messages_sent: sent.messages,
        parcels_sent: sent.parcels,
        parcels_resent: sent.resent,
        raw_bytes: sent.raw_bytes,
        sent_bytes: sent.sent_bytes,
        abandoned: sent.abandoned,
        actor_restarts: supervisor.restarts(),
        faults: supervisor.faults.clone(),
        ended: ended.into(),
    }
}

/// The machine's name, as the kernel has it.
fn machine_name() -> Result<String> {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .context("reading this machine's name (or give --host-name)")?;
    Ok(name.trim().to_owned())
}
