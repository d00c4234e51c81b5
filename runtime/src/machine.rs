//! What a run asks of the machine it starts on, checked before anything starts: the shared
//! memory its topics may write, the files its busiest process holds open, the threads of
//! its processes and the memory of its actors. A run past a limit is refused with the
//! limit, the figure and what to change; started, it would crash-loop.

use anyhow::{Result, bail};
use qnet::{Backend, QNets};
use wire::{LargestMessages, ShmFootprint, ShmLimits};

use rundir::config::RunConfig;

/// Files the busiest process (the launcher: it reads every process's status and orders
/// every process) holds open: its own, and per process of the run (measured: 58 with 11
/// processes, 90 with 19).
const FILES_BASE: u64 = 20;
const FILES_PER_PROCESS: u64 = 4;

/// Threads of a role process beyond one per core (its main thread and its log writer).
const THREADS_BEYOND_CORES: u64 = 2;

/// An actor process's resident memory: a base and its nets' activations, which grow with the
/// heightmap's pixels and the widest layer (measured: 85 MB at 112 x 112 and 102 MB at
/// 224 x 224 with trunks of 8 and 16 channels; 143 MB with 32 and 64 at 224 x 224).
const ACTOR_BASE_BYTES: u64 = 80 << 20;
const ACTOR_BYTES_PER_PIXEL_CHANNEL: u64 = 28;
/// Each environment of a process past its first: its scene, what it sees and its Q maps,
/// which grow with the heightmap's pixels (measured at 112 x 112, peak resident memory of
/// processes of 1, 2, 4 and 8 environments: 79, 86, 96 and 104 MB, 3.4 MB an environment
/// by least squares).
const ENV_BYTES_PER_PIXEL: u64 = 320;

/// The processes of a run on one machine and what they ask of it.
#[derive(Clone, Debug)]
pub struct Demand {
    /// Actor processes.
    actors: u64,
    /// Environments each actor process steps.
    envs_per_actor: u64,
    /// Every process that opens the run's topics: the actors, and the launcher, buffer and
    /// learner (or a joined host's bridge).
    processes: u64,
    limits: ShmLimits,
    shm: ShmFootprint,
    /// Bytes one actor process holds resident, all its environments.
    actor_bytes: u64,
    /// Bytes the replay holds in this process (0 on a joined host).
    replay_bytes: u64,
}

/// What this machine allows.
#[derive(Clone, Copy, Debug)]
pub struct Allowance {
    /// Free bytes in /dev/shm.
    pub shm_free: Option<u64>,
    /// The soft and hard limits on one process's open files.
    pub open_files: (u64, u64),
    /// Threads this user may still start (processes and threads count alike), if limited.
    pub threads_left: Option<u64>,
    pub cores: u64,
    /// Linux's MemAvailable.
    pub memory: Option<u64>,
}

impl Demand {
    /// A run of `config` with `actors` actor processes and `others` other processes here.
    pub fn new(config: &RunConfig, actors: u32, others: u32, replay_bytes: u64) -> Result<Self> {
        let processes = u64::from(actors) + u64::from(others);
        let side = config.side();
        let limits = shm_limits(config, processes as usize)?;
        let weights = QNets::new(&config.net, &Backend::Cpu.open()?.device)
            .to_bytes()?
            .len();
        let largest = LargestMessages {
            // Each item at most its observation and a push's next one, as steps carry them.
            batch: config.learner.batch_size as usize * 2 * limits.largest_step(),
            weights,
        };
        let widest = config.net.trunk_widths.iter().copied().max().unwrap_or(1) as u64;
        let pixels = (side * side) as u64;
        let envs_per_actor = u64::from(config.envs_per_actor);
        Ok(Self {
            actors: u64::from(actors),
            envs_per_actor,
            processes,
            limits,
            shm: limits.footprint(&largest),
            actor_bytes: ACTOR_BASE_BYTES
                + ACTOR_BYTES_PER_PIXEL_CHANNEL * pixels * widest
                + ENV_BYTES_PER_PIXEL * pixels * envs_per_actor.saturating_sub(1),
            replay_bytes,
        })
    }

    /// The limits every process of the run opens its topics with.
    pub fn limits(&self) -> ShmLimits {
        self.limits
    }

    /// For the run's start line: its processes and their shared memory.
    pub fn describe(&self) -> String {
        format!(
            "{} processes, shared memory {} written at most ({} reserved)",
            self.processes,
            megabytes(self.shm.written),
            megabytes(self.shm.reserved)
        )
    }

    fn open_files(&self) -> u64 {
        FILES_BASE + FILES_PER_PROCESS * self.processes
    }

    /// Refuses a run this machine cannot hold, naming the limit, the figure and what to
    /// change. The soft limit on open files is raised to the hard one when that suffices:
    /// the role processes inherit it.
    pub fn check(&self, machine: &Allowance) -> Result<()> {
        let fewer = "run fewer actors (--actors)";
        if let Some(free) = machine.shm_free
            && self.shm.written > free
        {
            bail!(
                "{} actors: the run's topics may write {} of shared memory, more than the {} \
                 free in /dev/shm; {fewer}, or give /dev/shm more room (a container's \
                 --shm-size)",
                self.actors,
                megabytes(self.shm.written),
                megabytes(free)
            );
        }
        let files = self.open_files();
        let (soft, hard) = machine.open_files;
        if files > hard {
            bail!(
                "{} actors: the launcher holds about {files} files open, more than this \
                 machine's limit of {hard} per process (ulimit -Hn); {fewer}, or raise the \
                 limit (nofile in /etc/security/limits.conf)",
                self.actors
            );
        }
        if files > soft {
            raise_open_files(hard)?;
        }
        let threads = self.processes * (machine.cores + THREADS_BEYOND_CORES);
        if let Some(left) = machine.threads_left
            && threads > left
        {
            bail!(
                "{} actors: {} processes start about {threads} threads, more than the {left} \
                 this user may still start (ulimit -u, /proc/sys/kernel/threads-max); {fewer}",
                self.actors,
                self.processes
            );
        }
        let memory = self.actors * self.actor_bytes + self.replay_bytes;
        if let Some(available) = machine.memory
            && memory > available
        {
            bail!(
                "{} actors of {} environments: about {} each ({} in all, with the replay's {}), \
                 more than the {} this machine has available; {fewer}, or step the same \
                 environments in fewer processes (a larger envs_per_actor): they share a \
                 process's base",
                self.actors,
                self.envs_per_actor,
                megabytes(self.actor_bytes),
                megabytes(memory),
                megabytes(self.replay_bytes),
                megabytes(available)
            );
        }
        Ok(())
    }
}

impl Allowance {
    /// This machine's, as Linux says now.
    pub fn here() -> Self {
        Self {
            shm_free: shm_free(),
            open_files: rlimit(libc::RLIMIT_NOFILE).unwrap_or((u64::MAX, u64::MAX)),
            threads_left: threads_left(),
            cores: std::thread::available_parallelism().map_or(1, |n| n.get() as u64),
            memory: rundir::config::available_memory(),
        }
    }
}

/// The limits every process of a run of `config` with `processes` processes on this machine
/// opens its topics with: the launcher's, and each role's from the same configuration.
pub fn shm_limits(config: &RunConfig, processes: usize) -> Result<ShmLimits> {
    Ok(
        ShmLimits::for_run(processes, wire::largest_step(config.sim.grid()?))
            .with_envs_per_process(config.envs_per_actor as usize),
    )
}

fn megabytes(bytes: u64) -> String {
    format!("{:.0} MB", bytes as f64 / 1e6)
}

fn shm_free() -> Option<u64> {
    let path = c"/dev/shm";
    let mut stat = std::mem::MaybeUninit::<libc::statvfs>::uninit();
    // SAFETY: a valid C string and a buffer statvfs fills; read only when it succeeded.
    if unsafe { libc::statvfs(path.as_ptr(), stat.as_mut_ptr()) } != 0 {
        return None;
    }
    // SAFETY: statvfs returned 0, so it filled the buffer.
    let stat = unsafe { stat.assume_init() };
    Some(stat.f_bavail * stat.f_frsize)
}

/// The soft and hard limits of `resource` (unlimited as `u64::MAX`).
fn rlimit(resource: libc::__rlimit_resource_t) -> Option<(u64, u64)> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit fills the struct it is given.
    if unsafe { libc::getrlimit(resource, &mut limit) } != 0 {
        return None;
    }
    Some((limit.rlim_cur, limit.rlim_max))
}

fn raise_open_files(to: u64) -> Result<()> {
    let limit = libc::rlimit {
        rlim_cur: to,
        rlim_max: to,
    };
    // SAFETY: setrlimit reads the struct it is given.
    if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &limit) } != 0 {
        bail!(
            "raising the limit on open files to {to}: {}",
            std::io::Error::last_os_error()
        );
    }
    Ok(())
}

/// Threads this user may still start: the lower of the user's limit (not applied to root)
/// and the kernel's, less the threads running now (all users': /proc/loadavg's count).
fn threads_left() -> Option<u64> {
    let kernel: u64 = std::fs::read_to_string("/proc/sys/kernel/threads-max")
        .ok()?
        .trim()
        .parse()
        .ok()?;
    // SAFETY: getuid cannot fail.
    let user = if unsafe { libc::getuid() } == 0 {
        u64::MAX
    } else {
        rlimit(libc::RLIMIT_NPROC).map_or(u64::MAX, |(soft, _)| soft)
    };
    let loadavg = std::fs::read_to_string("/proc/loadavg").ok()?;
    let running: u64 = loadavg
        .split_whitespace()
        .nth(3)?
        .split_once('/')?
        .1
        .parse()
        .ok()?;
    Some(kernel.min(user).saturating_sub(running))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stage1_config() -> RunConfig {
        RunConfig::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../configs/stage1.toml"
        )))
        .unwrap()
    }

    fn stage1(actors: u32) -> Demand {
        Demand::new(&stage1_config(), actors, 3, 0).unwrap()
    }

    fn roomy() -> Allowance {
        Allowance {
            shm_free: Some(64 << 30),
            open_files: (1 << 20, 1 << 20),
            threads_left: Some(1 << 20),
            cores: 2,
            memory: Some(64 << 30),
        }
    }

    #[test]
    fn a_run_the_machine_holds_passes() {
        stage1(64).check(&roomy()).unwrap();
        assert_eq!(stage1(64).limits().processes(), 67);
    }

    #[test]
    fn each_limit_refuses_with_its_figure_and_what_to_change() {
        let demand = stage1(64);
        let refused = |machine: Allowance| demand.check(&machine).unwrap_err().to_string();
        let shm = refused(Allowance {
            shm_free: Some(64 << 20),
            ..roomy()
        });
        assert!(
            shm.contains("/dev/shm") && shm.contains("--shm-size"),
            "{shm}"
        );
        let files = refused(Allowance {
            open_files: (1024, 200),
            ..roomy()
        });
        assert!(
            files.contains("288 files") && files.contains("200"),
            "{files}"
        );
        let threads = refused(Allowance {
            threads_left: Some(100),
            ..roomy()
        });
        assert!(threads.contains("268 threads"), "{threads}");
        let memory = refused(Allowance {
            memory: Some(1 << 30),
            ..roomy()
        });
        assert!(
            memory.contains("64 actors") && memory.contains("--actors"),
            "{memory}"
        );
        assert!(memory.contains("envs_per_actor"), "{memory}");
    }

    #[test]
    fn environments_sharing_a_process_ask_less_memory_than_processes_of_their_own() {
        let mut config = stage1_config();
        let alone = Demand::new(&config, 1, 3, 0).unwrap().actor_bytes;
        config.envs_per_actor = 8;
        let shared = Demand::new(&config, 1, 3, 0).unwrap().actor_bytes;
        assert!(shared > alone, "{shared} {alone}");
        assert!(
            shared < 2 * alone,
            "8 environments in one process: {shared} {alone}"
        );
    }
}
