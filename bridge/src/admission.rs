//! Which hosts may join a run and where their actors stand: each host's actor indices (after
//! the central host's own, kept when it joins again, and across `--resume` in `hosts.json`),
//! and what the run received from it.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use rundir::{HostReport, ProcessLayout};

use crate::join::{JoinReply, JoinRequest, Placement};

/// Incarnations between two joins of one host: above the restarts of an actor index a host
/// makes before it gives up.
pub const INCARNATIONS_PER_JOIN: u32 = 100;

/// What the central host admits hosts to.
pub struct Admission {
    pub run_id: String,
    /// The run's resolved config (TOML), handed to every host.
    pub config: String,
    /// The environments of the central host's own actors: indices `0..local_actors`; hosts'
    /// come after.
    pub local_actors: u32,
    /// How the run's environments fall into actor processes: a host's `--actors N` take
    /// the environments of `N` processes.
    pub layout: ProcessLayout,
    /// Where the hosts' places are kept, so a resumed run gives a host the same indices.
    pub hosts_file: PathBuf,
}

/// A joined host as the central host follows it: its report, and what the report leaves out.
#[derive(Clone, Debug, Default)]
pub(crate) struct JoinedHost {
    pub(crate) report: HostReport,
    /// Each actor stream's newest report: (index, incarnation) -> (steps sent, received).
    pub(crate) streams: BTreeMap<(u32, u32), (u64, u64)>,
    /// The newest parcel taken since it last joined: one sent again after its link came
    /// back is taken once.
    pub(crate) parcels_taken: u64,
    /// When its session was last lost before it was done.
    pub(crate) lost_at: Option<Instant>,
}

impl JoinedHost {
    pub(crate) fn owns(&self, actor: u32) -> bool {
        (self.report.first_actor..self.report.first_actor + self.report.actors).contains(&actor)
    }

    /// Whether the run's stop waits for it: it has not said it is done, and its session is
    /// present or was lost less than `grace` ago (a dropped link comes back by itself, and
    /// the order to stop reaches it then).
    pub(crate) fn awaited(&self, grace: Duration) -> bool {
        !self.report.done
            && (self.report.alive || self.lost_at.is_some_and(|at| at.elapsed() < grace))
    }

    /// Steps its actors reported sent that never arrived, from the streams seen in this
    /// process (a host seen only before a resume keeps its saved count).
    pub(crate) fn count_lost(&mut self) {
        if self.streams.is_empty() {
            return;
        }
        self.report.lost_in_flight = self
            .streams
            .values()
            .map(|&(sent, received)| sent.saturating_sub(received))
            .sum();
    }
}

/// The hosts of the run, shared by the bridge's threads.
pub(crate) struct Hosts {
    admission: Admission,
    pub(crate) hosts: BTreeMap<String, JoinedHost>,
    /// No host is admitted once the run is stopping.
    pub(crate) closing: bool,
    /// Hosts lost and back, in order (for the run's faults).
    pub(crate) news: Vec<HostNews>,
}

/// A host's session ended before it was done, or came back after that.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum HostNews {
    Lost(String),
    Back(String),
}

impl Hosts {
    pub(crate) fn load(admission: Admission) -> Result<Self> {
        let mut hosts = BTreeMap::new();
        if admission.hosts_file.exists() {
            let path = &admission.hosts_file;
            let text =
                std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
            let saved: Vec<HostReport> = serde_json::from_slice(&text)
                .with_context(|| format!("reading {}", path.display()))?;
            for mut report in saved {
                report.alive = false;
                report.done = false;
                let host = JoinedHost {
                    report,
                    ..JoinedHost::default()
                };
                hosts.insert(host.report.host.clone(), host);
            }
        }
        Ok(Self {
            admission,
            hosts,
            closing: false,
            news: Vec::new(),
        })
    }

    pub(crate) fn save(&self) -> Result<()> {
        let path = &self.admission.hosts_file;
        let tmp = path.with_extension("json.tmp");
        let hosts: Vec<&HostReport> = self.hosts.values().map(|h| &h.report).collect();
        std::fs::write(&tmp, serde_json::to_vec_pretty(&hosts)?)
            .with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))
    }

    /// Gives a host its place, or says why not. The same host joining again with as many
    /// actors keeps its indices, as its next incarnations.
    pub(crate) fn admit(&mut self, request: &JoinRequest) -> JoinReply {
        let refuse = |why: String| JoinReply::Refused(why);
        if self.closing {
            return refuse("the run is stopping".into());
        }
        if request.run_id != self.admission.run_id {
            return refuse(format!(
                "this is run {:?}, not {:?}",
                self.admission.run_id, request.run_id
            ));
        }
        if request.actors == 0 || request.host.is_empty() || request.host.contains(['/', '*']) {
            return refuse("a host needs a name without '/' or '*' and at least 1 actor".into());
        }
        let next_free = self
            .hosts
            .values()
            .map(|h| h.report.first_actor + h.report.actors)
            .fold(self.admission.local_actors, u32::max);
        let layout = self.admission.layout;
        let indices = layout.environments(request.actors);
        let host = self
            .hosts
            .entry(request.host.clone())
            .or_insert_with(|| JoinedHost {
                report: HostReport {
                    host: request.host.clone(),
                    first_actor: next_free,
                    actors: indices,
                    ..HostReport::default()
                },
                ..JoinedHost::default()
            });
        let report = &mut host.report;
        if report.actors != indices {
            return refuse(format!(
                "host {:?} joined this run before with {} actors: join with as many, or under \
                 another --host-name",
                report.host,
                layout.processes(report.actors)
            ));
        }
        let placement = Placement {
            first_actor: report.first_actor,
            incarnation: report.joins * INCARNATIONS_PER_JOIN,
            config: self.admission.config.clone(),
        };
        report.joins += 1;
        report.done = false;
        host.parcels_taken = 0;
        match self.save() {
            Ok(()) => JoinReply::Accepted(placement),
            Err(e) => refuse(format!("the central host cannot record the join: {e:#}")),
        }
    }

    pub(crate) fn host(&mut self, name: &str) -> &mut JoinedHost {
        self.hosts
            .entry(name.to_owned())
            .or_insert_with(|| JoinedHost {
                report: HostReport {
                    host: name.to_owned(),
                    ..HostReport::default()
                },
                ..JoinedHost::default()
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hosts(dir: &std::path::Path) -> Hosts {
        Hosts::load(Admission {
            run_id: "r".into(),
            config: "stage = 1".into(),
            local_actors: 2,
            layout: ProcessLayout::new(1),
            hosts_file: dir.join("hosts.json"),
        })
        .unwrap()
    }

    fn request(host: &str, actors: u32) -> JoinRequest {
        JoinRequest {
            run_id: "r".into(),
            host: host.into(),
            actors,
        }
    }

    fn accepted(reply: JoinReply) -> Placement {
        match reply {
            JoinReply::Accepted(placement) => placement,
            JoinReply::Refused(why) => panic!("refused: {why}"),
        }
    }

    #[test]
    fn the_stop_waits_for_a_host_not_done_while_it_is_here_or_just_lost() {
        let grace = Duration::from_secs(30);
        let here = JoinedHost {
            report: HostReport {
                alive: true,
                ..HostReport::default()
            },
            ..JoinedHost::default()
        };
        assert!(here.awaited(grace));
        let mut done = here.clone();
        done.report.done = true;
        assert!(!done.awaited(grace));
        let just_lost = JoinedHost {
            lost_at: Some(Instant::now()),
            ..JoinedHost::default()
        };
        assert!(just_lost.awaited(grace));
        let long_lost = JoinedHost {
            lost_at: Instant::now().checked_sub(Duration::from_secs(31)),
            ..JoinedHost::default()
        };
        assert!(long_lost.lost_at.is_some() && !long_lost.awaited(grace));
        assert!(!JoinedHost::default().awaited(grace), "never here");
    }

    #[test]
    fn hosts_get_indices_after_the_local_actors_and_keep_them() {
        let dir = tempfile::tempdir().unwrap();
        let mut table = hosts(dir.path());
        let a = accepted(table.admit(&request("a", 3)));
        let b = accepted(table.admit(&request("b", 2)));
        assert_eq!((a.first_actor, a.incarnation), (2, 0));
        assert_eq!((b.first_actor, b.incarnation), (5, 0));
        assert_eq!(a.config, "stage = 1");
        // Joining again: the same indices, later incarnations; kept across a resume.
        let again = accepted(hosts(dir.path()).admit(&request("a", 3)));
        assert_eq!(
            (again.first_actor, again.incarnation),
            (2, INCARNATIONS_PER_JOIN)
        );
    }

    #[test]
    fn bad_joins_are_refused_with_the_reason() {
        let dir = tempfile::tempdir().unwrap();
        let mut table = hosts(dir.path());
        accepted(table.admit(&request("a", 3)));
        let refused = |reply| match reply {
            JoinReply::Refused(why) => why,
            JoinReply::Accepted(_) => panic!("accepted"),
        };
        assert!(refused(table.admit(&request("a", 4))).contains("before with 3 actors"));
        assert!(refused(table.admit(&request("c", 0))).contains("at least 1 actor"));
        let mut other_run = request("c", 1);
        other_run.run_id = "s".into();
        assert!(refused(table.admit(&other_run)).contains("not \"s\""));
        table.closing = true;
        assert!(refused(table.admit(&request("c", 1))).contains("stopping"));
    }
}
