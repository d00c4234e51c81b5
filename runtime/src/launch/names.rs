//! The names a run goes under: its id, the run `--resume` continues, and the namespaces of
//! its shared memory and of each launch of it.

use std::path::Path;
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result, anyhow};
use wire::ShmLimits;

use rundir::run_dir::RunDir;

pub(super) fn default_run_id(stage: u8) -> String {
    let secs = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    format!("stage{stage}-{secs}")
}

/// The newest run directory under `logs` (the one `--resume` continues by default).
pub(super) fn newest_run(logs: &Path) -> Result<String> {
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
