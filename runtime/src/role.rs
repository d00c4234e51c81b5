//! The roles of a run as the launcher and the role processes name them: [`RoleId`] (the
//! buffer, the learner, or one incarnation of an actor index), what a role process runs
//! ([`run_role`]), and the entry of a child process (`pushgrasp role`).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;
use mcaplog::LogLevel;
use wire::{Message, Outbox, Role, Status, Topic, Transport};

use crate::Lifeline;
use crate::actor::ActorId;
use crate::memory::sampling_memory;
use crate::process_log::open_log;
use rundir::config::RunConfig;
use rundir::run_dir::RunDir;
use rundir::write_json;

/// One role of a run: its kind ([`Role`]) and which one: an actor's index and incarnation,
/// the buffer's or the learner's incarnation (0, then one more for each restart).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RoleId {
    Buffer(u32),
    Learner(u32),
    Actor(ActorId),
}

impl RoleId {
    /// The role's name in logs, reports and shared-memory nodes (`actor-<index>-<incarnation>`
    /// for an actor, `buffer-<incarnation>` or `learner-<incarnation>` for a restarted buffer
    /// or learner).
    pub fn name(self) -> String {
        match self {
            RoleId::Actor(id) => format!("{}-{}-{}", Role::Actor, id.index, id.incarnation),
            RoleId::Buffer(0) | RoleId::Learner(0) => self.kind().name().into(),
            RoleId::Buffer(incarnation) | RoleId::Learner(incarnation) => {
                format!("{}-{incarnation}", self.kind())
            }
        }
    }

    /// How many times this role was started before in the run.
    pub fn incarnation(self) -> u32 {
        match self {
            RoleId::Buffer(incarnation) | RoleId::Learner(incarnation) => incarnation,
            RoleId::Actor(id) => id.incarnation,
        }
    }

    /// The same role started again.
    pub fn next_incarnation(self) -> RoleId {
        match self {
            RoleId::Buffer(incarnation) => RoleId::Buffer(incarnation + 1),
            RoleId::Learner(incarnation) => RoleId::Learner(incarnation + 1),
            RoleId::Actor(id) => RoleId::Actor(ActorId {
                index: id.index,
                incarnation: id.incarnation + 1,
            }),
        }
    }

    /// Whose status reports show this role alive: an actor's own, the buffer's or the
    /// learner's whatever its incarnation.
    pub fn reporter(self) -> String {
        match self {
            RoleId::Actor(_) => self.name(),
            other => other.kind().name().into(),
        }
    }

    pub fn kind(self) -> Role {
        match self {
            RoleId::Buffer(_) => Role::Buffer,
            RoleId::Learner(_) => Role::Learner,
            RoleId::Actor(_) => Role::Actor,
        }
    }
}

/// Where a role starts from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StartFrom {
    /// The run directory's saved state (the checkpoint, the buffer's snapshot).
    pub resume: bool,
    /// For a restarted learner: the newest weight version published before it, which its
    /// own versions pass.
    pub weights_after: u64,
}

/// Runs a role to its end and writes its report to the run directory; a failure is also
/// announced on the status topic, so the launcher can say why.
pub fn run_role(
    transport: &dyn Transport,
    id: RoleId,
    config: &RunConfig,
    dir: &RunDir,
    from: StartFrom,
    lifeline: &Lifeline,
) -> Result<()> {
    let name = id.name();
    std::fs::create_dir_all(dir.reports())?;
    let report = dir.report(&name);
    let log = open_log(dir, &name, config)?;
    log.log_line(LogLevel::Info, &format!("{name} started"))?;
    let work = || match id {
        RoleId::Buffer(incarnation) => {
            let start = crate::buffer::Start {
                resume: from.resume,
                incarnation,
            };
            crate::buffer::run(transport, config, dir, start, &log, lifeline)
                .and_then(|r| write_json(&report, &r))
        }
        RoleId::Learner(incarnation) => {
            let start = crate::learner::Start {
                resume: from.resume,
                incarnation,
                weights_after: from.weights_after,
            };
            crate::learner::run(transport, config, dir, start, &log, lifeline)
                .and_then(|r| write_json(&report, &r))
        }
        // One report per environment, each under the name its own process would have.
        RoleId::Actor(first) => crate::actor::run(transport, config, first, &log, lifeline)
            .and_then(|reports| {
                reports.iter().try_for_each(|r| {
                    let id = RoleId::Actor(ActorId {
                        index: r.actor,
                        incarnation: r.incarnation,
                    });
                    write_json(&dir.report(&id.name()), r)
                })
            }),
    };
    // A role with a process of its own logs that process's memory; threads of one process
    // leave it to the launcher's log.
    let result = if lifeline.own_process() {
        sampling_memory(&log, work)
    } else {
        work()
    };
    match &result {
        Ok(()) => log.log_line(LogLevel::Info, &format!("{name} stopped"))?,
        Err(e) => log.log_line(LogLevel::Fatal, &format!("{name} failed: {e:#}"))?,
    }
    log.finish()?;
    if let Err(e) = &result {
        let failed = Status::Failed {
            role: id.kind(),
            error: format!("{e:#}"),
        };
        if let Ok(mut status) = Outbox::open(transport, Topic::Status) {
            let _ = status.send(&Message::Status(failed));
        }
    }
    result
}

/// `pushgrasp role`: one role of a run, started by the launcher (not by hand).
#[derive(Args)]
pub struct RoleArgs {
    /// actor, buffer or learner.
    pub role: Role,
    /// The run directory (holds the resolved config.toml).
    #[arg(long)]
    pub run_dir: PathBuf,
    /// The namespace of the run's shared-memory services (this launch's, from the launcher).
    #[arg(long)]
    pub shm_namespace: String,
    /// The run's processes on this machine, from which its topics' limits follow (the
    /// launcher's figure: every process must give the same).
    #[arg(long)]
    pub shm_processes: usize,
    #[arg(long)]
    pub resume: bool,
    /// The actor's index.
    #[arg(long, default_value_t = 0)]
    pub index: u32,
    /// How many times this actor index (or the buffer, or the learner) was started before.
    #[arg(long, default_value_t = 0)]
    pub incarnation: u32,
    /// A restarted learner: the newest weight version published before it.
    #[arg(long, default_value_t = 0)]
    pub weights_after: u64,
}

impl RoleArgs {
    pub fn id(&self) -> RoleId {
        match self.role {
            Role::Buffer => RoleId::Buffer(self.incarnation),
            Role::Learner => RoleId::Learner(self.incarnation),
            Role::Actor => RoleId::Actor(ActorId {
                index: self.index,
                incarnation: self.incarnation,
            }),
        }
    }
}

/// The entry of a child process: the role over shared memory, reports to the run directory.
pub fn role_process(args: &RoleArgs) -> Result<()> {
    // Ctrl-C in a terminal reaches the whole process group: the launcher alone decides, and
    // stops the roles in order through the control topic.
    signal_hook::flag::register(
        signal_hook::consts::SIGINT,
        Arc::new(AtomicBool::new(false)),
    )
    .context("installing the signal handler")?;
    let dir = RunDir::new(&args.run_dir);
    let config = RunConfig::load(&dir.config())?;
    let id = args.id();
    let limits = crate::machine::shm_limits(&config, args.shm_processes)?;
    let transport = wire::ShmTransport::new(&args.shm_namespace, &id.name(), limits)?;
    let from = StartFrom {
        resume: args.resume,
        weights_after: args.weights_after,
    };
    let lifeline = Lifeline::child(
        dir.launcher_alive(),
        Duration::from_secs_f64(config.run.heartbeat_timeout_s),
    );
    run_role(&transport, id, &config, &dir, from, &lifeline)
}
