//! Supervision of a run's roles: starting each as a child process (or a thread), noticing
//! when one exits, restarting a crashed role as its next incarnation, stopping roles of one
//! kind in order, killing what does not stop, and the faults it saw.

use std::collections::BTreeMap;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use mcaplog::{LogLevel, RunLog};
use wire::{ChannelTransport, Control, Message, Outbox, Role, ShmLimits};

use crate::Lifeline;
use crate::actor::ActorId;
use crate::role::{RoleId, StartFrom, run_role};
use crate::worker::Worker;
use rundir::config::RunConfig;
use rundir::run_dir::RunDir;
use rundir::{Fault, ProcessEntry, write_json};

mod fault;
mod restart;

use fault::last_error;

/// Crashes of one actor index the launcher restarts before it gives up on the run.
const MAX_RESTARTS: u32 = 10;
/// Crashes of the learner, or of the buffer, it restarts before it gives up.
const MAX_ROLE_RESTARTS: u32 = 3;
/// How a role killed for its silence is described.
const HUNG: &str = "sent no status report";
/// How long the buffer or the learner may be silent before the roles that wait on it are
/// not judged by their own silence (they report four times a second).
const QUIET: Duration = Duration::from_secs(1);
/// What a user can do after the buffer or the learner failed for good: what they saved
/// before (the rotating generations) is intact.
pub const RESUME_HINT: &str = "the run's last checkpoint and buffer snapshot stand: \
     `pushgrasp train --resume --run-id <id>` (or `pipeline` with its `--id`) continues it \
     once that is fixed";
/// How long a role may take to stop once told to.
const STOP_TIMEOUT: Duration = Duration::from_secs(120);

/// How the launcher starts roles.
pub enum Wiring {
    /// Role processes meeting in this launch's shared memory, whose topics they open with
    /// the run's limits.
    Processes {
        namespace: String,
        limits: ShmLimits,
    },
    Threads {
        transport: ChannelTransport,
    },
}

struct Slot {
    spec: RoleId,
    worker: Worker,
    /// Set once it exited (cleanly or not) and was dealt with.
    done: bool,
    started: Instant,
    /// Why the launcher killed it, when it was silent too long.
    hung: Option<String>,
}

pub struct Supervisor {
    wiring: Wiring,
    config: RunConfig,
    dir: RunDir,
    resume: bool,
    slots: Vec<Slot>,
    /// The launcher's own log.
    pub log: RunLog,
    /// Restarts per actor index.
    crashes: BTreeMap<u32, u32>,
    /// Roles started again after a failure, of every kind.
    restarts: u32,
    /// The cause of each role's (actor index's, buffer's, learner's) latest failure before
    /// it first reported: the same again is a configuration error, not bad luck.
    startup_failures: BTreeMap<(&'static str, u32), String>,
    /// Every role that failed, in order.
    pub faults: Vec<Fault>,
    started: Instant,
    /// The buffer and the learner now running (their latest incarnations).
    buffer: RoleId,
    learner: RoleId,
    /// The newest weight version published when the learner last died.
    weights_after: u64,
    /// When the launcher's heartbeat file was last touched.
    last_beat: Option<Instant>,
}

impl Supervisor {
    pub fn new(wiring: Wiring, config: RunConfig, dir: RunDir, resume: bool, log: RunLog) -> Self {
        Self {
            wiring,
            config,
            dir,
            resume,
            slots: Vec::new(),
            log,
            crashes: BTreeMap::new(),
            restarts: 0,
            startup_failures: BTreeMap::new(),
            faults: Vec::new(),
            started: Instant::now(),
            buffer: RoleId::Buffer(0),
            learner: RoleId::Learner(0),
            weights_after: 0,
            last_beat: None,
        }
    }

    /// A role's fault, or a joined host's (which the supervisor does not start itself).
    pub fn record_fault(&mut self, role: String, cause: &str, restarted: bool) {
        self.faults.push(Fault {
            role,
            at_s: self.started.elapsed().as_secs_f64(),
            cause: cause.into(),
            restarted,
            lost_messages: None,
        });
    }

    pub fn config(&self) -> &RunConfig {
        &self.config
    }

    /// Starts a role: a child process running `pushgrasp role`, or a thread of this one.
    pub fn start(&mut self, spec: RoleId) -> Result<()> {
        beat(&self.dir, &mut self.last_beat)?;
        let worker = match &self.wiring {
            Wiring::Processes { namespace, limits } => {
                let mut command = Command::new(std::env::current_exe()?);
                command
                    .args(["role", spec.kind().name()])
                    .arg("--run-dir")
                    .arg(self.dir.path())
                    .args(["--shm-namespace", namespace])
                    .args(["--shm-processes", &limits.processes().to_string()]);
                let from = self.start_from(spec);
                if from.resume {
                    command.arg("--resume");
                }
                match spec {
                    RoleId::Actor(id) => {
                        command
                            .args(["--index", &id.index.to_string()])
                            .args(["--incarnation", &id.incarnation.to_string()]);
                    }
                    RoleId::Learner(incarnation) if incarnation > 0 => {
                        command
                            .args(["--incarnation", &incarnation.to_string()])
                            .args(["--weights-after", &from.weights_after.to_string()]);
                    }
                    RoleId::Buffer(incarnation) if incarnation > 0 => {
                        command.args(["--incarnation", &incarnation.to_string()]);
                    }
                    _ => {}
                }
                let log = self.dir.log(&spec.name());
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
                let (transport, config, dir, start) = (
                    transport.clone(),
                    self.config.clone(),
                    self.dir.clone(),
                    self.start_from(spec),
                );
                let handle = std::thread::Builder::new()
                    .name(spec.name())
                    .spawn(move || {
                        run_role(&transport, spec, &config, &dir, start, &Lifeline::thread())
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
            started: Instant::now(),
            hung: None,
        });
        self.write_processes()
    }

    /// Whether `spec` starts from the run directory's state (a restarted buffer or learner
    /// always does: its newest snapshot or checkpoint), and the weight version a restarted
    /// learner's must pass.
    fn start_from(&self, spec: RoleId) -> StartFrom {
        match spec {
            RoleId::Learner(incarnation) if incarnation > 0 => StartFrom {
                resume: true,
                weights_after: self.weights_after,
            },
            RoleId::Buffer(incarnation) if incarnation > 0 => StartFrom {
                resume: true,
                weights_after: 0,
            },
            _ => StartFrom {
                resume: self.resume,
                weights_after: 0,
            },
        }
    }

    /// The buffer now running (its latest incarnation).
    pub fn buffer(&self) -> RoleId {
        self.buffer
    }

    /// The learner now running (its latest incarnation).
    pub fn learner(&self) -> RoleId {
        self.learner
    }

    /// Whether this launch started the actor process of `id` (not one of a launch before
    /// that this run resumed).
    pub fn started_actor(&self, id: ActorId) -> bool {
        self.slots.iter().any(|s| s.spec == RoleId::Actor(id))
    }

    /// The next incarnation of each actor index a resumed run starts: one past any that ran
    /// before (its report or log names it), so the buffer tells their streams apart.
    pub fn next_incarnations(&self) -> Result<BTreeMap<u32, u32>> {
        let mut next = BTreeMap::new();
        for dir in [self.dir.path().to_path_buf(), self.dir.reports()] {
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
        write_json(&self.dir.processes(), &entries)
    }

    /// Says `message` on the console and in the launcher's log.
    pub fn announce(&mut self, message: &str) -> Result<()> {
        self.say(LogLevel::Warning, message)
    }

    /// Prints `message` for the person running the launcher, and logs it at `level`.
    pub fn say(&mut self, level: LogLevel, message: &str) -> Result<()> {
        eprintln!("{message}");
        Ok(self.log.log_line(level, message)?)
    }

    /// Tells one kind of role to stop and waits for every one of them; kills what does not
    /// stop in time.
    pub fn stop(&mut self, role: Role, control: &mut Outbox) -> Result<Vec<String>> {
        control.send(&Message::Control(Control::Stop(role)))?;
        let deadline = Instant::now() + STOP_TIMEOUT;
        let mut problems = Vec::new();
        for slot in self
            .slots
            .iter_mut()
            .filter(|s| !s.done && s.spec.kind() == role)
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
                // A role that subscribed after the order was sent (one just started) gets
                // it from the topic's history only now.
                control.refresh()?;
                beat(&self.dir, &mut self.last_beat)?;
                std::thread::sleep(Duration::from_millis(20));
            };
            slot.done = true;
            if let Err(why) = outcome {
                let why = last_error(&self.dir.log(&slot.spec.name())).unwrap_or(why);
                problems.push(format!("{}: {why}", slot.spec.name()));
            }
        }
        self.write_processes()?;
        Ok(problems)
    }

    /// Roles started again after a failure so far: actors, the buffer and the learner.
    pub fn restarts(&self) -> u32 {
        self.restarts
    }

    pub fn kill_all(&mut self) {
        for slot in self.slots.iter_mut().filter(|s| !s.done) {
            slot.worker.kill();
            slot.done = true;
        }
    }
}

/// Touches the heartbeat file the roles watch (once a second): while it stays fresh, the
/// launcher is alive and supervising.
fn beat(dir: &RunDir, last: &mut Option<Instant>) -> Result<()> {
    if last.is_some_and(|at| at.elapsed() < Duration::from_secs(1)) {
        return Ok(());
    }
    let path = dir.launcher_alive();
    std::fs::write(&path, b"").with_context(|| format!("writing {}", path.display()))?;
    *last = Some(Instant::now());
    Ok(())
}
