//! A joined host's bridge: asks the central host for a place, then carries the local actors'
//! steps and episode ends up in parcels, and their progress reports; and brings the weights
//! down into the local weights topic and tells when the run ordered the actors to stop or
//! the central host is gone. Two threads: up and down.
//!
//! Steps are published only while the central host listens: while it does not (its link is
//! down), the up thread holds its parcel and stops reading, so the actors wait on their
//! bounded queues; memory does not grow. Parcels the link lost are sent again when it is back.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use wire::{Control, Message, Role, Status, Topic, Transport};
use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::handlers::RingChannelHandler;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::sample::{Sample, SampleKind};
use zenoh::{Session, query::QueryTarget};

use crate::join::{self, JoinReply, JoinRequest, Placement};
use crate::link::{self, Keys, PARCELS_IN_FLIGHT, Stream};
use crate::parcel::{self, Packer};

/// How long a join waits for the central host's answer.
const JOIN_TIMEOUT: Duration = Duration::from_secs(10);

/// How often a waiting thread looks again.
const POLL: Duration = Duration::from_millis(20);

/// Asks the central host for a place in the run.
pub fn join(session: &Session, keys: &Keys, request: &JoinRequest) -> Result<Placement> {
    let replies = session
        .get(keys.join())
        .payload(join::encode(request))
        .target(QueryTarget::All)
        .timeout(JOIN_TIMEOUT)
        .wait()
        .map_err(|e| anyhow::anyhow!("asking to join: {e}"))?;
    let reply = replies.recv().map_err(|_| {
        anyhow::anyhow!(
            "run {:?} did not answer within {JOIN_TIMEOUT:?}: is it started with --listen, \
                 and is it this run?",
            request.run_id
        )
    })?;
    let sample = reply
        .result()
        .map_err(|e| anyhow::anyhow!("the central host could not answer: {e:?}"))?;
    match join::decode::<JoinReply>(&sample.payload().to_bytes())
        .context("the central host's answer")?
    {
        JoinReply::Accepted(placement) => Ok(placement),
        JoinReply::Refused(why) => bail!("the central host refused to let us join: {why}"),
    }
}

/// What the up thread did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct UpReport {
    /// Wire messages published (steps and episode ends).
    pub messages: u64,
    pub parcels: u64,
    pub raw_bytes: u64,
    pub sent_bytes: u64,
    /// Messages thrown away because the central host was gone for good.
    pub abandoned: u64,
    /// Parcels sent again because the link dropped before the central host took them.
    pub resent: u64,
}

/// Flags the join loop and the bridge's threads share.
#[derive(Default)]
struct Flags {
    /// The actors have stopped: send what is left, then say done.
    finishing: AtomicBool,
    /// The central host is gone for good: drain the actors' steps without sending them.
    abandon: AtomicBool,
    /// The run ordered the actors to stop.
    stop_ordered: AtomicBool,
    /// Since when the central host's presence has not been seen (None while it is).
    central_gone_since: Mutex<Option<Instant>>,
    /// Times the central host's presence came back (or first came): parcels it may not
    /// have taken are sent again.
    central_returns: AtomicU64,
    /// Stop the down thread.
    closed: AtomicBool,
}

/// A joined host's bridge, running until [`HostBridge::finish`].
pub struct HostBridge {
    session: Session,
    flags: Arc<Flags>,
    up: JoinHandle<Result<UpReport>>,
    down: JoinHandle<Result<()>>,
    _token: LivelinessToken,
}

impl HostBridge {
    /// Starts carrying between `transport` (this host's shared memory) and the central host,
    /// as `host` of the run. Subscriptions come first, then this host's presence, so the
    /// central host's re-sent weights find them.
    pub fn start(
        session: Session,
        keys: Keys,
        host: &str,
        transport: Arc<dyn Transport + Send + Sync>,
    ) -> Result<Self> {
        // Not seen yet: gone since now, until its presence arrives.
        let flags = Arc::new(Flags {
            central_gone_since: Mutex::new(Some(Instant::now())),
            ..Flags::default()
        });
        // Each thread reports once its ends are open: steps published before the up thread
        // subscribed would be lost, and weights before the down thread did.
        let (ready_tx, ready_rx) = crossbeam_channel::bounded::<Result<()>>(2);
        let down = {
            let (session, keys, flags, transport, ready) = (
                session.clone(),
                keys.clone(),
                flags.clone(),
                transport.clone(),
                ready_tx.clone(),
            );
            std::thread::Builder::new()
                .name("bridge-down".into())
                .spawn(move || carry_down(&session, &keys, &flags, transport.as_ref(), ready))?
        };
        let up = {
            let (session, flags, host) = (session.clone(), flags.clone(), host.to_owned());
            let keys = keys.clone();
            std::thread::Builder::new()
                .name("bridge-up".into())
                .spawn(move || {
                    carry_up(&session, &keys, &host, &flags, transport.as_ref(), ready_tx)
                })?
        };
        for _ in 0..2 {
            let opened = ready_rx
                .recv()
                .unwrap_or_else(|_| Err(anyhow::anyhow!("a bridge thread ended")));
            if let Err(e) = opened {
                // The other thread ends too.
                for flag in [&flags.finishing, &flags.abandon, &flags.closed] {
                    flag.store(true, Ordering::Release);
                }
                return Err(e);
            }
        }
        let token = session
            .liveliness()
            .declare_token(keys.host(host))
            .wait()
            .map_err(|e| anyhow::anyhow!("declaring this host's presence: {e}"))?;
        Ok(Self {
            session,
            flags,
            up,
            down,
            _token: token,
        })
    }

    /// Whether the run has ordered the actors to stop.
    pub fn stop_ordered(&self) -> bool {
        self.flags.stop_ordered.load(Ordering::Acquire)
    }

    /// How long the central host has been gone (zero while it is present).
    pub fn central_gone_for(&self) -> Duration {
        lock(&self.flags.central_gone_since).map_or(Duration::ZERO, |since| since.elapsed())
    }

    /// Whether a bridge thread has ended (its error comes with [`HostBridge::finish`]).
    pub fn failed(&self) -> bool {
        self.up.is_finished() || self.down.is_finished()
    }

    /// After the actors stopped: sends what they left and says this host is done (or, after
    /// [`HostBridge::abandon`], throws it away, counted); then closes the session. Once the
    /// central host has been gone for `give_up`, what it has not taken is thrown away too:
    /// it waits for hosts only so long after its stop order, then ends, and over a slow link
    /// the actors' last steps can take longer than that.
    pub fn finish(self, give_up: Duration) -> Result<UpReport> {
        self.flags.finishing.store(true, Ordering::Release);
        while !self.up.is_finished() {
            if self.central_gone_for() > give_up {
                self.abandon();
            }
            std::thread::sleep(POLL);
        }
        let up = self
            .up
            .join()
            .unwrap_or_else(|_| Err(anyhow::anyhow!("the bridge's up thread panicked")));
        self.flags.closed.store(true, Ordering::Release);
        let down = self
            .down
            .join()
            .unwrap_or_else(|_| Err(anyhow::anyhow!("the bridge's down thread panicked")));
        self.session
            .close()
            .wait()
            .map_err(|e| anyhow::anyhow!("closing the Zenoh session: {e}"))?;
        let up = up?;
        down?;
        Ok(up)
    }

    /// Stops waiting for the central host: what is held is thrown away (counted), and
    /// the actors' queues drain.
    pub fn abandon(&self) {
        self.flags.abandon.store(true, Ordering::Release);
    }
}

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|e| e.into_inner())
}

/// The parcels this host sent that the central host has not taken yet, and its
/// acknowledgements. A parcel in flight when the link dropped is lost with the Zenoh session
/// that carried it: the window keeps every parcel until it is taken and sends them all again
/// once the central host listens again (it takes each number once).
struct Window {
    taken: Subscriber<RingChannelHandler<Sample>>,
    /// The newest parcel the central host took.
    newest_taken: u64,
    /// Parcels sent and not taken, oldest first: [`PARCELS_IN_FLIGHT`] at most.
    unacked: VecDeque<(u64, ZBytes)>,
    /// The central host's returns seen (`Flags::central_returns`).
    returns_seen: u64,
    /// Parcels sent again after the link came back.
    resent: u64,
}

impl Window {
    fn new(taken: Subscriber<RingChannelHandler<Sample>>) -> Self {
        Self {
            taken,
            newest_taken: 0,
            unacked: VecDeque::new(),
            returns_seen: 0,
            resent: 0,
        }
    }

    /// Waits until parcel `number` may go: the central host listens and has taken all but a
    /// few of those before it. False when told to abandon. While it waits the actors are
    /// held back (they report from their waiting sends), and it connects to local actors
    /// that start meanwhile (`steps_in`), so what they send before they stop outlives them.
    fn wait_for_room(
        &mut self,
        publisher: &Publisher<'_>,
        steps_in: &mut dyn wire::Subscriber,
        number: u64,
        flags: &Flags,
    ) -> Result<bool> {
        let mut relinked = false;
        loop {
            if flags.abandon.load(Ordering::Acquire) {
                return Ok(false);
            }
            while let Some(sample) = self.taken.try_recv().map_err(|e| anyhow::anyhow!("{e}"))? {
                if let Some(bytes) = sample.payload().to_bytes().first_chunk::<8>() {
                    self.newest_taken = self.newest_taken.max(u64::from_le_bytes(*bytes));
                }
            }
            while self
                .unacked
                .front()
                .is_some_and(|&(n, _)| n <= self.newest_taken)
            {
                self.unacked.pop_front();
            }
            let returns = flags.central_returns.load(Ordering::Acquire);
            relinked |= returns != self.returns_seen;
            self.returns_seen = returns;
            let matching = publisher
                .matching_status()
                .wait()
                .map_err(|e| anyhow::anyhow!("{e}"))?
                .matching();
            if !matching {
                relinked = true;
            } else {
                if relinked {
                    for (_, parcel) in &self.unacked {
                        put(publisher, parcel.clone())?;
                        self.resent += 1;
                    }
                    relinked = false;
                }
                if number - 1 - self.newest_taken.min(number - 1) < PARCELS_IN_FLIGHT {
                    return Ok(true);
                }
            }
            steps_in.refresh()?;
            std::thread::sleep(POLL);
        }
    }

    /// Sends parcel `number` and keeps it until it is taken.
    fn send(&mut self, publisher: &Publisher<'_>, number: u64, parcel: Vec<u8>) -> Result<()> {
        let parcel = ZBytes::from(parcel);
        put(publisher, parcel.clone())?;
        self.unacked.push_back((number, parcel));
        Ok(())
    }
}

fn put(publisher: &Publisher<'_>, parcel: ZBytes) -> Result<()> {
    publisher
        .put(parcel)
        .wait()
        .map_err(|e| anyhow::anyhow!("sending steps: {e}"))
}

/// Opens a bridge thread's ends and tells [`HostBridge::start`] whether that worked.
fn opened<T>(
    ready: crossbeam_channel::Sender<Result<()>>,
    open: impl FnOnce() -> Result<T>,
) -> Result<T> {
    let ends = open();
    let _ = ready.send(match &ends {
        Ok(_) => Ok(()),
        Err(e) => Err(anyhow::anyhow!("{e:#}")),
    });
    ends
}

/// The local actors' steps and episode ends up in parcels, their reports as they come.
fn carry_up(
    session: &Session,
    keys: &Keys,
    host: &str,
    flags: &Flags,
    transport: &dyn Transport,
    ready: crossbeam_channel::Sender<Result<()>>,
) -> Result<UpReport> {
    let (mut steps_in, mut status_in, steps_out, status_out, taken) = opened(ready, || {
        Ok((
            transport.subscriber(Topic::Steps)?,
            transport.subscriber(Topic::Status)?,
            link::publisher(session, Stream::Steps, keys.stream(Stream::Steps, host))?,
            link::publisher(session, Stream::Status, keys.stream(Stream::Status, host))?,
            link::newest_subscriber(session, keys.stream(Stream::Taken, host))?,
        ))
    })?;
    let mut window = Window::new(taken);
    let mut report = UpReport::default();
    let mut packer = Packer::default();
    loop {
        // Read before looking at the flag: once finishing is seen, a round that finds
        // nothing means the stopped actors' last steps are all taken.
        let finishing = flags.finishing.load(Ordering::Acquire);
        let mut reports = Vec::new();
        while status_in.receive(&mut |bytes| {
            if matches!(
                wire::decode(bytes),
                Ok(Message::Status(Status::Actor { .. }))
            ) {
                reports.push(bytes.to_vec());
            }
        })? {}
        for bytes in reports {
            status_out
                .put(bytes)
                .wait()
                .map_err(|e| anyhow::anyhow!("sending a report: {e}"))?;
        }
        while !packer.full() && steps_in.receive(&mut |bytes| packer.push(bytes))? {}
        if packer.is_empty() {
            if finishing {
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
            continue;
        }
        let messages = packer.len() as u64;
        report.raw_bytes += packer.raw_len() as u64;
        let number = report.parcels + 1;
        if !window.wait_for_room(&steps_out, steps_in.as_mut(), number, flags)? {
            packer.clear();
            report.abandoned += messages;
            continue;
        }
        let parcel = packer.seal(number);
        report.sent_bytes += parcel.len() as u64;
        window.send(&steps_out, number, parcel)?;
        report.messages += messages;
        report.parcels += 1;
    }
    let number = report.parcels + 1;
    if window.wait_for_room(&steps_out, steps_in.as_mut(), number, flags)? {
        window.send(&steps_out, number, parcel::done(number))?;
        // Leave once the central host took it (its session may otherwise end first).
        let deadline = Instant::now() + Duration::from_secs(10);
        while window.newest_taken < number && Instant::now() < deadline {
            window.wait_for_room(
                &steps_out,
                steps_in.as_mut(),
                number + PARCELS_IN_FLIGHT,
                flags,
            )?;
            std::thread::sleep(POLL);
        }
    }
    report.resent = window.resent;
    Ok(report)
}

/// The weights into the local weights topic; the run's order to stop the actors, and the
/// central host's presence, into the flags.
fn carry_down(
    session: &Session,
    keys: &Keys,
    flags: &Flags,
    transport: &dyn Transport,
    ready: crossbeam_channel::Sender<Result<()>>,
) -> Result<()> {
    let (weights_in, control_in, central, mut weights_out) = opened(ready, || {
        Ok((
            link::newest_subscriber(session, keys.stream(Stream::Weights, ""))?,
            link::subscriber(session, keys.stream(Stream::Control, ""))?,
            session
                .liveliness()
                .declare_subscriber(keys.central())
                .history(true)
                .wait()
                .map_err(|e| anyhow::anyhow!("watching the central host: {e}"))?,
            transport.publisher(Topic::Weights)?,
        ))
    })?;
    let mut last_refresh = Instant::now();
    while !flags.closed.load(Ordering::Acquire) {
        while let Some(sample) = central.try_recv().map_err(|e| anyhow::anyhow!("{e}"))? {
            let gone = sample.kind() != SampleKind::Put;
            let mut gone_since = lock(&flags.central_gone_since);
            if !gone && gone_since.is_some() {
                flags.central_returns.fetch_add(1, Ordering::AcqRel);
            }
            *gone_since = gone.then(Instant::now);
        }
        while let Some(sample) = control_in.try_recv().map_err(|e| anyhow::anyhow!("{e}"))? {
            if let Ok(Message::Control(Control::Stop(Role::Actor))) =
                wire::decode(&sample.payload().to_bytes())
            {
                flags.stop_ordered.store(true, Ordering::Release);
            }
        }
        match weights_in
            .recv_timeout(POLL)
            .map_err(|e| anyhow::anyhow!("{e}"))?
        {
            Some(sample) => weights_out.send(&sample.payload().to_bytes())?,
            // An actor started since the last weights gets them.
            None if last_refresh.elapsed() > Duration::from_millis(200) => {
                weights_out.refresh()?;
                last_refresh = Instant::now();
            }
            None => {}
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use wire::ChannelTransport;

    /// A session that meets no other: no scouting, no endpoints.
    fn lone_session() -> Session {
        let mut config = zenoh::Config::default();
        config
            .insert_json5("scouting/multicast/enabled", "false")
            .unwrap();
        zenoh::open(config).wait().unwrap()
    }

    #[test]
    fn a_host_whose_central_host_is_gone_gives_up_its_last_steps() {
        let transport = Arc::new(ChannelTransport::new());
        let bridge =
            HostBridge::start(lone_session(), Keys::new("r"), "h", transport.clone()).unwrap();
        // A stopped actor's last steps, which no central host will take.
        let mut steps = transport.publisher(Topic::Steps).unwrap();
        for _ in 0..3 {
            steps.send(&[7; 100]).unwrap();
        }
        let (done, finished) = crossbeam_channel::bounded(1);
        std::thread::spawn(move || {
            let _ = done.send(bridge.finish(Duration::from_millis(300)));
        });
        let report = finished
            .recv_timeout(Duration::from_secs(30))
            .expect("the host waited on for a central host that is gone")
            .unwrap();
        assert_eq!(report.abandoned, 3, "{report:?}");
        assert_eq!(report.messages, 0, "{report:?}");
    }
}
