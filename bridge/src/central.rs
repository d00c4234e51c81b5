//! The central host's bridge: admits joining hosts, takes their steps into the local steps
//! topic (the buffer reads them like any local actor's) and their actors' progress into the
//! local status topic, and sends the learner's weights and the launcher's orders to every
//! host at once. Threads: joins, up (steps, reports, presence), down (weights, orders).
//! Each parcel is acknowledged once its steps are in the steps topic: a host has a few in
//! flight at most, so Zenoh's reader of its link never waits on the buffer. Only steps and
//! episode ends of a host's own actors enter; anything else is counted as rejected.
//! One idea at about 420 lines of code: the join answers and both threads share one state.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use rundir::HostReport;
use wire::{Message, Status, Topic, Transport};
use zenoh::Wait;
use zenoh::sample::SampleKind;
use zenoh::{Session, liveliness::LivelinessToken};

use crate::admission::{Admission, HostNews, Hosts, JoinedHost};
use crate::join::{self, JoinReply, JoinRequest};
use crate::link::{self, Keys, Stream};
use crate::parcel::{self, Parcel};
use crate::session::CENTRAL_LEASE_MS;

/// How long each thread waits for news before it looks at its stop flag.
const POLL: Duration = Duration::from_millis(50);

/// How long the run's stop waits for a host whose session was lost to come back: a host
/// whose link dropped finds the central host gone within its lease, then reconnects as TCP
/// and Zenoh back off (seconds more on a loaded machine).
const RETURN_GRACE: Duration = Duration::from_millis(3 * CENTRAL_LEASE_MS);

/// The central host's bridge, running until [`Central::close`].
pub struct Central {
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<Result<()>>>,
    _token: LivelinessToken,
}

/// One of the bridge's threads.
type Thread = fn(&Shared) -> Result<()>;

/// What the bridge's threads share.
struct Shared {
    session: Session,
    keys: Keys,
    hosts: Mutex<Hosts>,
    stop: AtomicBool,
    /// A host appeared: the newest weights and orders go out again.
    resend: AtomicBool,
    transport: Arc<dyn Transport + Send + Sync>,
}

impl Central {
    /// Starts the bridge on `session` (see [`crate::session::listen`]), taking hosts' steps
    /// into `transport`'s steps topic. The buffer must listen already.
    pub fn start(
        session: Session,
        transport: Arc<dyn Transport + Send + Sync>,
        admission: Admission,
    ) -> Result<Self> {
        let shared = Arc::new(Shared {
            keys: Keys::new(&admission.run_id),
            hosts: Mutex::new(Hosts::load(admission)?),
            session,
            stop: AtomicBool::new(false),
            resend: AtomicBool::new(false),
            transport,
        });
        let mut threads = Vec::new();
        let bodies: [(&str, Thread); 3] = [
            ("bridge-joins", answer_joins),
            ("bridge-up", carry_up),
            ("bridge-down", carry_down),
        ];
        for (name, body) in bodies {
            let shared = shared.clone();
            threads.push(
                std::thread::Builder::new()
                    .name(name.into())
                    .spawn(move || body(&shared))
                    .with_context(|| format!("starting the bridge's {name} thread"))?,
            );
        }
        let token = shared
            .session
            .liveliness()
            .declare_token(shared.keys.central())
            .wait()
            .map_err(|e| anyhow::anyhow!("declaring the central host's presence: {e}"))?;
        Ok(Self {
            shared,
            threads,
            _token: token,
        })
    }

    fn hosts(&self) -> MutexGuard<'_, Hosts> {
        lock(&self.shared.hosts)
    }

    /// Hosts lost or back since the last call.
    pub fn take_news(&self) -> Vec<HostNews> {
        std::mem::take(&mut self.hosts().news)
    }

    /// Whether a bridge thread has failed (its error comes with [`Central::close`]).
    pub fn failed(&self) -> bool {
        self.threads.iter().any(JoinHandle::is_finished)
    }

    /// Refuses further joins, then waits until every live host, and every host lost less
    /// than `RETURN_GRACE` ago, has said it is done (they stop when the launcher's order
    /// to stop the actors reaches them) or `timeout` passes. Returns the hosts that did not
    /// finish.
    pub fn wait_for_hosts(&self, timeout: Duration) -> Vec<String> {
        self.hosts().closing = true;
        let deadline = Instant::now() + timeout;
        loop {
            let waiting: Vec<String> = self
                .hosts()
                .hosts
                .values()
                .filter(|h| h.awaited(RETURN_GRACE))
                .map(|h| h.report.host.clone())
                .collect();
            if waiting.is_empty() || Instant::now() > deadline || self.failed() {
                return waiting;
            }
            std::thread::sleep(POLL);
        }
    }

    /// Stops the bridge and closes the session; returns the hosts' final counts.
    pub fn close(self) -> Result<Vec<HostReport>> {
        self.shared.stop.store(true, Ordering::Release);
        let mut outcome = Ok(());
        for thread in self.threads {
            let result = thread
                .join()
                .unwrap_or_else(|_| Err(anyhow::anyhow!("a bridge thread panicked")));
            if outcome.is_ok() {
                outcome = result;
            }
        }
        let report = {
            let mut hosts = lock(&self.shared.hosts);
            hosts.hosts.values_mut().for_each(JoinedHost::count_lost);
            let _ = hosts.save();
            hosts.hosts.values().map(|h| h.report.clone()).collect()
        };
        self.shared
            .session
            .close()
            .wait()
            .map_err(|e| anyhow::anyhow!("closing the Zenoh session: {e}"))?;
        outcome.map(|()| report)
    }
}

fn lock(hosts: &Mutex<Hosts>) -> MutexGuard<'_, Hosts> {
    hosts.lock().unwrap_or_else(|e| e.into_inner())
}

fn zenoh_error(what: &str) -> impl FnOnce(zenoh::Error) -> anyhow::Error + '_ {
    move |e| anyhow::anyhow!("{what}: {e}")
}

/// Answers join queries until stopped.
fn answer_joins(shared: &Shared) -> Result<()> {
    let Shared {
        session,
        keys,
        hosts,
        stop,
        ..
    } = shared;
    let queryable = session
        .declare_queryable(keys.join())
        .wait()
        .map_err(zenoh_error("declaring the join queryable"))?;
    while !stop.load(Ordering::Acquire) {
        let Some(query) = queryable
            .recv_timeout(POLL)
            .map_err(zenoh_error("receiving a join"))?
        else {
            continue;
        };
        let bytes = query.payload().map(|p| p.to_bytes()).unwrap_or_default();
        let reply = match join::decode::<JoinRequest>(&bytes) {
            Ok(request) => lock(hosts).admit(&request),
            Err(e) => JoinReply::Refused(e.to_string()),
        };
        if let JoinReply::Refused(why) = &reply {
            eprintln!("refused a host: {why}");
        }
        query
            .reply(query.key_expr().clone(), join::encode(&reply))
            .wait()
            .map_err(zenoh_error("answering a join"))?;
    }
    Ok(())
}

/// Hosts' steps into the local steps topic, their actors' reports into the local status
/// topic, which hosts come and go, until stopped. A host's leaving is judged only when the
/// steps queue is empty: its last parcel (done or not) arrived before its session ended.
fn carry_up(shared: &Shared) -> Result<()> {
    let Shared {
        session,
        keys,
        hosts,
        stop,
        resend,
        transport,
    } = shared;
    let steps_in = link::subscriber(session, keys.every_host(Stream::Steps))?;
    let status_in = link::newest_subscriber(session, keys.every_host(Stream::Status))?;
    let presence = session
        .liveliness()
        .declare_subscriber(keys.every_host_token())
        .history(true)
        .wait()
        .map_err(zenoh_error("watching the hosts"))?;
    let mut steps_out = transport.publisher(Topic::Steps)?;
    let mut status_out = transport.publisher(Topic::Status)?;
    while !stop.load(Ordering::Acquire) {
        while let Some(sample) = status_in
            .try_recv()
            .map_err(zenoh_error("receiving a report"))?
        {
            if let Some(host) = keys.host_of(Stream::Status, sample.key_expr().as_str()) {
                take_report(
                    &mut lock(hosts),
                    host,
                    &sample.payload().to_bytes(),
                    &mut *status_out,
                )?;
            }
        }
        // One parcel a round, so that reports are read between parcels while hosts keep the
        // queue full (the buffer sets the pace).
        let parcel = steps_in
            .try_recv()
            .map_err(zenoh_error("receiving steps"))?;
        let took = parcel.is_some();
        if let Some(sample) = parcel
            && let Some(host) = keys.host_of(Stream::Steps, sample.key_expr().as_str())
            && let Some(number) =
                take_parcel(hosts, host, &sample.payload().to_bytes(), &mut *steps_out)?
        {
            link::put(
                session,
                Stream::Taken,
                keys.stream(Stream::Taken, host),
                number.to_le_bytes().to_vec(),
            )?;
        }
        // Comings and goings only with no parcel waiting: a host's last parcels are in.
        while let Some(sample) = (!took)
            .then(|| presence.try_recv())
            .transpose()
            .map_err(zenoh_error("watching the hosts"))?
            .flatten()
        {
            let Some(name) = sample.key_expr().as_str().rsplit('/').next() else {
                continue;
            };
            let mut hosts = lock(hosts);
            let host = hosts.host(name);
            if sample.kind() == SampleKind::Put {
                let back = !host.report.alive && host.report.lost_links > 0;
                host.report.alive = true;
                resend.store(true, Ordering::Release);
                if back {
                    hosts.news.push(HostNews::Back(name.to_owned()));
                }
            } else if host.report.alive {
                host.report.alive = false;
                // Done: it said it had sent everything, and leaving is what it should do.
                if !host.report.done {
                    host.report.lost_links += 1;
                    host.lost_at = Some(Instant::now());
                    hosts.news.push(HostNews::Lost(name.to_owned()));
                }
            }
        }
        if !took {
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    Ok(())
}

/// An actor's progress report from `host`: passed on if the actor is the host's own.
fn take_report(
    hosts: &mut Hosts,
    host: &str,
    bytes: &[u8],
    status_out: &mut dyn wire::Publisher,
) -> Result<()> {
    let host = hosts.host(host);
    match wire::decode(bytes) {
        Ok(Message::Status(Status::Actor {
            actor,
            incarnation,
            steps_sent,
            ..
        })) if host.owns(actor) => {
            host.streams.entry((actor, incarnation)).or_default().0 = steps_sent;
            status_out.send(bytes)?;
        }
        _ => host.report.rejected += 1,
    }
    Ok(())
}

/// A parcel from `host`: its steps and episode ends into the steps topic, when they are its
/// actors'. Returns the parcel's number once taken (None for a damaged one).
fn take_parcel(
    hosts: &Mutex<Hosts>,
    host: &str,
    bytes: &[u8],
    steps_out: &mut dyn wire::Publisher,
) -> Result<Option<u64>> {
    let (number, parcel) = match parcel::unpack(bytes) {
        Ok(unpacked) => unpacked,
        Err(e) => {
            eprintln!("host {host}: {e}");
            lock(hosts).host(host).report.rejected += 1;
            return Ok(None);
        }
    };
    {
        let mut hosts = lock(hosts);
        let host = hosts.host(host);
        // Sent again after the link came back, and taken before: acknowledged again only.
        if number <= host.parcels_taken {
            return Ok(Some(number));
        }
        host.parcels_taken = number;
    }
    let messages = match parcel {
        Parcel::Messages(messages) => messages,
        Parcel::Done => {
            lock(hosts).host(host).report.done = true;
            return Ok(Some(number));
        }
    };
    for message in messages {
        // Decoded whole, so that nothing the buffer cannot read reaches it (that would end
        // its run); checked under the lock, sent outside it: the buffer may hold a step back.
        let admitted = {
            let mut hosts = lock(hosts);
            let host = hosts.host(host);
            let admitted = match wire::decode(&message) {
                Ok(Message::Step(step)) if host.owns(step.origin.actor) => {
                    host.report.steps_received += 1;
                    let origin = step.origin;
                    host.streams
                        .entry((origin.actor, origin.incarnation))
                        .or_default()
                        .1 += 1;
                    true
                }
                Ok(Message::EpisodeEnd(end)) if host.owns(end.origin.actor) => {
                    host.report.episode_ends_received += 1;
                    true
                }
                _ => false,
            };
            if !admitted {
                host.report.rejected += 1;
            }
            admitted
        };
        if admitted {
            steps_out.send(&message)?;
        }
    }
    Ok(Some(number))
}

/// The learner's weights and the launcher's orders to every host, the newest of each again
/// whenever a host appears (`resend`).
fn carry_down(shared: &Shared) -> Result<()> {
    let Shared {
        session,
        keys,
        stop,
        resend,
        transport,
        ..
    } = shared;
    let mut weights_in = transport.subscriber(Topic::Weights)?;
    let mut control_in = transport.subscriber(Topic::Control)?;
    let mut newest: [Option<Vec<u8>>; 2] = [None, None];
    while !stop.load(Ordering::Acquire) {
        let resend = resend.swap(false, Ordering::AcqRel);
        let mut busy = false;
        for (slot, (subscriber, stream)) in newest.iter_mut().zip([
            (&mut weights_in, Stream::Weights),
            (&mut control_in, Stream::Control),
        ]) {
            let mut fresh = false;
            while subscriber.receive(&mut |bytes| *slot = Some(bytes.to_vec()))? {
                fresh = true;
            }
            busy |= fresh;
            if let Some(bytes) = slot.as_ref().filter(|_| fresh || resend) {
                link::put(session, stream, keys.stream(stream, ""), bytes.clone())?;
            }
        }
        if !busy {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parcel::Packer;
    use wire::{ChannelTransport, EpisodeEnd, Origin};

    fn episode_end(actor: u32, seq: u64) -> Vec<u8> {
        let mut bytes = Vec::new();
        let end = EpisodeEnd {
            origin: Origin {
                actor,
                incarnation: 0,
                seq,
            },
            episode: seq,
            goal: 1,
            grasped: None,
            steps: 1,
            trial: false,
        };
        wire::encode_into(&Message::EpisodeEnd(end), &mut bytes);
        bytes
    }

    fn parcel(number: u64, messages: &[Vec<u8>]) -> Vec<u8> {
        let mut packer = Packer::default();
        for message in messages {
            packer.push(message);
        }
        packer.seal(number)
    }

    #[test]
    fn a_parcel_sent_again_is_acknowledged_and_taken_once() {
        let dir = tempfile::tempdir().unwrap();
        let hosts = Mutex::new(
            Hosts::load(Admission {
                run_id: "r".into(),
                config: String::new(),
                local_actors: 1,
                layout: rundir::ProcessLayout::new(1),
                hosts_file: dir.path().join("hosts.json"),
            })
            .unwrap(),
        );
        let join = || {
            lock(&hosts).admit(&JoinRequest {
                run_id: "r".into(),
                host: "h".into(),
                actors: 1,
            })
        };
        assert!(matches!(join(), JoinReply::Accepted(_)));
        let transport = ChannelTransport::new();
        let mut steps_in = transport.subscriber(Topic::Steps).unwrap();
        let mut steps_out = transport.publisher(Topic::Steps).unwrap();
        let mut take = |bytes: &[u8]| take_parcel(&hosts, "h", bytes, &mut *steps_out).unwrap();
        let (first, second) = (
            parcel(1, &[episode_end(1, 0)]),
            parcel(2, &[episode_end(1, 1)]),
        );
        assert_eq!(take(&first), Some(1));
        assert_eq!(take(&second), Some(2));
        // The link dropped before the acknowledgements arrived: both come again.
        assert_eq!(take(&first), Some(1));
        assert_eq!(take(&second), Some(2));
        let mut delivered = 0;
        while steps_in.receive(&mut |_| delivered += 1).unwrap() {}
        assert_eq!(delivered, 2);
        assert_eq!(lock(&hosts).host("h").report.episode_ends_received, 2);
        // A host that joins again numbers its parcels from 1 again.
        assert!(matches!(join(), JoinReply::Accepted(_)));
        assert_eq!(take(&parcel(1, &[episode_end(1, 2)])), Some(1));
        assert_eq!(lock(&hosts).host("h").report.episode_ends_received, 3);
    }
}
