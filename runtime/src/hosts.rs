//! The central host's side of a run across machines (`train --listen`): the run's secret, the
//! bridge that admits joining hosts and carries their steps into the buffer's topic, the
//! hosts the run lost, and, at the stop, waiting for every host to send its last steps.

use std::sync::Arc;
use std::time::Duration;

use anyhow::{Result, bail};
use bridge::{Admission, Central, Endpoint, HostNews, RunSecret};
use rundir::HostReport;
use wire::Transport;

use crate::supervisor::Supervisor;
use rundir::config::RunConfig;
use rundir::run_dir::RunDir;

/// How long joined hosts may take to stop their actors and send their last steps.
const HOSTS_STOP_TIMEOUT: Duration = Duration::from_secs(120);

/// What opening the link needs, kept until the buffer listens.
struct Pending {
    endpoint: Endpoint,
    secret: RunSecret,
    admission: Admission,
    transport: Arc<dyn Transport + Send + Sync>,
}

/// The link to joined hosts: none for a run on one host.
#[derive(Default)]
pub struct HostLink {
    pending: Option<Pending>,
    central: Option<Central>,
}

impl HostLink {
    /// A link that will listen at `endpoint` (none without one); writes the run's secret
    /// first (kept when the run is resumed, so its hosts join again with the same file).
    pub fn new(
        endpoint: Option<&Endpoint>,
        run_id: &str,
        dir: &RunDir,
        config: &RunConfig,
        transport: &Arc<dyn Transport + Send + Sync>,
    ) -> Result<Self> {
        let Some(endpoint) = endpoint.cloned() else {
            return Ok(Self::default());
        };
        let secret = RunSecret::create_or_keep(&dir.secret(), run_id)?;
        let admission = Admission {
            run_id: run_id.into(),
            config: toml::to_string(config)?,
            local_actors: config.layout().environments(config.actors),
            layout: config.layout(),
            hosts_file: dir.hosts_file(),
        };
        Ok(Self {
            pending: Some(Pending {
                endpoint,
                secret,
                admission,
                transport: transport.clone(),
            }),
            central: None,
        })
    }

    /// Starts listening (once the buffer listens: hosts' steps go straight to it).
    pub fn open(&mut self) -> Result<()> {
        let Some(pending) = self.pending.take() else {
            return Ok(());
        };
        bridge::traces::install(true);
        let session = bridge::session::listen(&pending.endpoint, &pending.secret)?;
        let run_id = pending.admission.run_id.clone();
        self.central = Some(Central::start(
            session,
            pending.transport,
            pending.admission,
        )?);
        println!(
            "listening at {endpoint} for hosts; on each: pushgrasp join {endpoint} --run-id {run_id} --secret-file {} --actors N",
            pending.secret.file.display(),
            endpoint = pending.endpoint,
        );
        Ok(())
    }

    /// Records the hosts lost since the last look as faults (the run goes on without them);
    /// a failed bridge ends the run.
    pub fn check(&mut self, supervisor: &mut Supervisor) -> Result<()> {
        let Some(central) = &self.central else {
            return Ok(());
        };
        if central.failed() {
            let central = self.central.take().expect("checked above");
            central.close()?;
            bail!("the bridge to the joined hosts stopped");
        }
        record_news(central, supervisor);
        Ok(())
    }

    /// After the local actors stopped: waits for every live host to send its last steps.
    pub fn wait_for_hosts(&self, supervisor: &mut Supervisor) {
        let Some(central) = &self.central else {
            return;
        };
        let unfinished = central.wait_for_hosts(HOSTS_STOP_TIMEOUT);
        record_news(central, supervisor);
        for host in unfinished {
            let cause = format!("did not finish within {HOSTS_STOP_TIMEOUT:?} of the stop");
            eprintln!("host {host} {cause}");
            supervisor.record_fault(format!("host {host}"), &cause, false);
        }
    }

    /// Closes the link; the hosts' counts for the run's summary.
    pub fn close(self) -> Result<Vec<HostReport>> {
        match self.central {
            Some(central) => central.close(),
            None => Ok(Vec::new()),
        }
    }
}

/// The hosts lost since the last look, as faults (the run goes on without them); a host
/// back (its link again, or joined again) marks its fault as recovered.
fn record_news(central: &Central, supervisor: &mut Supervisor) {
    for news in central.take_news() {
        match news {
            HostNews::Lost(host) => {
                let cause =
                    "its session ended before it was done (the host died or its link dropped)";
                eprintln!("host {host}: {cause}; the run goes on without it");
                supervisor.record_fault(format!("host {host}"), cause, false);
            }
            HostNews::Back(host) => {
                eprintln!("host {host} is back");
                let role = format!("host {host}");
                if let Some(fault) = supervisor
                    .faults
                    .iter_mut()
                    .rev()
                    .find(|f| f.role == role && !f.restarted)
                {
                    fault.restarted = true;
                }
            }
        }
    }
}

/// A line per joined host for the run's closing words.
pub fn print_hosts(hosts: &[HostReport]) {
    for host in hosts {
        println!(
            "host {}: actors {}..{}, joined {} times, {} steps and {} episode ends received, {} lost in flight, {} refused",
            host.host,
            host.first_actor,
            host.first_actor + host.actors,
            host.joins,
            host.steps_received,
            host.episode_ends_received,
            host.lost_in_flight,
            host.rejected
        );
    }
}
