//! A joined host's bridge: asks the central host for a place, then carries the local actors'
//! steps and episode ends up in parcels, and their progress reports; and brings the weights
//! down into the local weights topic and tells when the run ordered the actors to stop or
//! the central host is gone. Two threads: up and down.
//!
//! Steps are published only while the central host listens: while it does not (its link is
//! down), the up thread holds its parcel and stops reading, so the actors wait on their
//! bounded queues; memory does not grow. Parcels the link lost are sent again when it is back.

mod carry;
mod flags;

use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use wire::Transport;
use zenoh::Wait;
use zenoh::liveliness::LivelinessToken;
use zenoh::{Session, query::QueryTarget};

use crate::join::{self, JoinReply, JoinRequest, Placement};
use crate::link::Keys;

pub use carry::UpReport;
use carry::{carry_down, carry_up};
use flags::{Flags, POLL, lock};

/// How long a join waits for the central host's answer.
const JOIN_TIMEOUT: Duration = Duration::from_secs(10);

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

#[cfg(test)]
mod tests {
    use super::*;
    use wire::{ChannelTransport, Topic};

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
