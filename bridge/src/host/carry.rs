//! The bridge's two threads: up (the local actors' steps and episode ends in parcels, sent
//! again when the link lost them, and their reports) and down (the weights, the run's order
//! to stop, the central host's presence).

use std::collections::VecDeque;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::Result;
use wire::{Control, Message, Role, Status, Topic, Transport};
use zenoh::Session;
use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::handlers::RingChannelHandler;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::sample::{Sample, SampleKind};

use crate::link::{self, Keys, PARCELS_IN_FLIGHT, Stream};
use crate::parcel::{self, Packer};

use super::flags::{Flags, POLL, lock};
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

/// The parcels this host sent that the central host has not taken yet, and its
/// acknowledgements. A parcel in flight when the link dropped is lost with the Zenoh session
/// that carried it: the window keeps every parcel until it is taken and sends them again,
/// oldest first, once the central host listens again (it takes each number once).
///
/// They go again one at a time, each once the one before is taken: the central host's lease
/// counts whole Zenoh batches, and all of them at once in one batch would outlast it on a
/// slow link, which would drop the session again (and again, at each return).
struct Window {
    taken: Subscriber<RingChannelHandler<Sample>>,
    /// The newest parcel the central host took.
    newest_taken: u64,
    /// Parcels sent and not taken, oldest first: [`PARCELS_IN_FLIGHT`] at most.
    unacked: VecDeque<(u64, ZBytes)>,
    /// The central host's returns seen (`Flags::central_returns`).
    returns_seen: u64,
    /// Since the link came back: the newest parcel sent again (the newest taken before the
    /// first); None once every parcel the link lost went again.
    resending: Option<u64>,
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
            resending: None,
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
                    self.resending = Some(self.newest_taken);
                    relinked = false;
                }
                self.resend_next(publisher)?;
                if self.resending.is_none()
                    && number - 1 - self.newest_taken.min(number - 1) < PARCELS_IN_FLIGHT
                {
                    return Ok(true);
                }
            }
            steps_in.refresh()?;
            std::thread::sleep(POLL);
        }
    }

    /// While parcels the link lost wait to go again: the next of them, once the one sent
    /// again before it was taken.
    fn resend_next(&mut self, publisher: &Publisher<'_>) -> Result<()> {
        let Some(newest_resent) = self.resending else {
            return Ok(());
        };
        if self.newest_taken < newest_resent {
            return Ok(());
        }
        self.resending = match self.unacked.iter().find(|&&(n, _)| n > newest_resent) {
            Some((n, parcel)) => {
                put(publisher, parcel.clone())?;
                self.resent += 1;
                Some(*n)
            }
            None => None,
        };
        Ok(())
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

/// Opens a bridge thread's ends and tells [`HostBridge::start`](super::HostBridge::start)
/// whether that worked.
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
pub(super) fn carry_up(
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
pub(super) fn carry_down(
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
