//! A private Slurm on this machine for the tests that submit jobs (`start.sh`): one node, or
//! several node names served by one slurmd each (slurmd's multiple-slurmd mode), stopped
//! when dropped.

use std::net::TcpListener;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use tempfile::TempDir;

pub struct Slurm {
    state: TempDir,
    /// The `SLURM_CONF` that `sbatch` and `squeue` need.
    pub conf: String,
}

impl Slurm {
    /// Starts one with `nodes` nodes, or says why it cannot and returns `None`.
    pub fn start(nodes: u32) -> Option<Slurm> {
        let state = tempfile::tempdir().unwrap();
        let port = || {
            TcpListener::bind("127.0.0.1:0")
                .unwrap()
                .local_addr()
                .unwrap()
                .port()
        };
        let output = Command::new("bash")
            .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/slurm/start.sh"))
            .arg(state.path())
            .env("SLURMCTLD_PORT", port().to_string())
            .env("SLURMD_PORT", port().to_string())
            .env("SLURM_NODES", nodes.to_string())
            .output()
            .expect("bash runs");
        let slurm = Slurm {
            conf: String::from_utf8_lossy(&output.stdout)
                .lines()
                .find_map(|line| line.strip_prefix("SLURM_CONF="))
                .unwrap_or_default()
                .to_string(),
            state,
        };
        if !output.status.success() || slurm.conf.is_empty() {
            eprintln!(
                "skipping the Slurm test: no {nodes}-node Slurm could be started here ({}): {}",
                output.status,
                String::from_utf8_lossy(&output.stderr).trim()
            );
            return None;
        }
        Some(slurm)
    }
}

impl Drop for Slurm {
    fn drop(&mut self) {
        let pids = std::fs::read_to_string(self.state.path().join("pids")).unwrap_or_default();
        for pid in pids.split_whitespace() {
            let _ = Command::new("kill").args(["-TERM", pid]).status();
        }
        // A job step's slurmstepd can outlive its slurmd: what still carries this Slurm's
        // config in its environment goes too.
        let ours = format!("SLURM_CONF={}\0", self.conf);
        for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
            let environ = std::fs::read(entry.path().join("environ")).unwrap_or_default();
            if environ.windows(ours.len()).any(|w| w == ours.as_bytes()) {
                let pid = entry.file_name().to_string_lossy().into_owned();
                let _ = Command::new("kill").args(["-KILL", &pid]).status();
            }
        }
        // The daemons write into the state directory until they are gone.
        let alive = |pid: &str| Path::new(&format!("/proc/{pid}")).exists();
        let deadline = Instant::now() + Duration::from_secs(10);
        while pids.split_whitespace().any(alive) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}
