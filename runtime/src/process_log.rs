//! A process's log: its MCAP file in the run directory, opened with the run's resolved
//! config, and the warnings a role passes on to the launcher beside writing them there.

use std::collections::BTreeMap;
use std::time::Duration;

use anyhow::Result;
use mcaplog::{LogLevel, RunLog};
use wire::{Message, Outbox, Role, Status};

use rundir::config::RunConfig;
use rundir::run_dir::RunDir;

/// Passes a role's warning on to the launcher, which prints it, and into the role's log.
pub fn warn(status: &mut Outbox, log: &RunLog, role: Role, warning: String) -> Result<()> {
    log.log_line(LogLevel::Warning, &warning)?;
    status.send(&Message::Status(Status::Warning { role, warning }))?;
    Ok(())
}

/// A process's MCAP log in the run directory, opened with the run's resolved config.
pub fn open_log(dir: &RunDir, name: &str, config: &RunConfig) -> Result<RunLog> {
    if !config.logging.enabled {
        return Ok(RunLog::disabled(name));
    }
    let minutes = config.logging.segment_minutes;
    let options = mcaplog::Options {
        segment_every: (minutes > 0.0).then(|| Duration::from_secs_f64(minutes * 60.0)),
        ..mcaplog::Options::default()
    };
    // A log of this name in the run's directory is an earlier process's of the same run (a
    // resumed run's launcher, buffer and learner): it is kept, and this one goes on after it.
    let log = RunLog::continue_with(dir.mcap(name), name, options)?;
    let config = BTreeMap::from([("toml".to_string(), toml::to_string(config)?)]);
    log.metadata("config", &config)?;
    Ok(log)
}
