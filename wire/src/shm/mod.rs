//! iceoryx2 shared memory between the processes of one machine: the transport `train` uses.
//!
//! Each process owns one iceoryx2 node; each topic is a publish-subscribe service of byte
//! slices named `pushgrasp/<run id>/<topic>`, so two runs on one machine never meet. Every
//! process opens a topic with the same settings, whoever comes first creates it, and with
//! limits sized from the run's processes ([`ShmLimits`]). A subscriber reads a message in
//! place, in the publisher's shared memory.
//!
//! What iceoryx2 does that a caller must know:
//! - A subscriber connects to a new publisher when it next looks for messages. Until then
//!   the publisher's messages wait in a buffer of the topic's size; when it is full a
//!   lossless publisher here waits for the subscriber (iceoryx2 itself would drop them).
//! - A lossless publisher whose subscriber's buffer is full waits (spinning, then sleeping)
//!   until the subscriber reads, drops its end, or its process is found dead and cleaned up
//!   (every new node cleans up dead ones, as does [`ShmTransport::remove_stale`]). A message
//!   sent while no subscriber exists is dropped, as over channels.
//! - What a publisher of steps sent stays readable after it exits or is killed, once the
//!   subscriber has connected to it: it reserves its memory for the run's largest step up
//!   front, which the subscriber maps as it connects. (Memory that grows as messages do, as
//!   on the other topics, is mapped only as its first message is read: an actor that exited
//!   before the buffer read its first step took that step with it.) A publisher that exits
//!   before the subscriber first looked (received, or [`Subscriber::refresh`]) takes its
//!   unread messages with it (a killed one, when it is cleaned up).
//! - A subscriber of steps returns a step's memory to its publisher only after reading three
//!   more, or 250 us later (see `kept`), so a publisher's shared memory holds those too.
//! - History (the newest weights, the newest order) reaches a subscriber that joins later
//!   only when the publisher next sends or calls [`Publisher::refresh`].
//!
//! Its tests take it past 400 lines; the code itself is under 400.

use std::collections::{HashSet, VecDeque};
use std::time::{Duration, Instant};

use iceoryx2::node::NodeView;
use iceoryx2::port::BackpressureInfo;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::{
    BackpressureStrategy, CallbackProgression, Config, FileName, Node, NodeBuilder, NodeName,
    NodeState, SemanticString, ServiceName, SignalHandlingMode, ipc,
};
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;

use crate::error::TransportError;
use crate::topic::{Delivery, Fan, Topic};
use crate::transport::{Publisher, Subscriber, Transport, WAITING_EVERY};
use publisher::{ShmPublisher, wait_for_room};

mod limits;
mod publisher;
mod stale;

pub use limits::{LargestMessages, ShmFootprint, ShmLimits};

/// Every name this transport gives starts with this.
const PREFIX: &str = "pushgrasp";

/// Longest run id accepted (iceoryx2 limits node names to 128 bytes).
pub const MAX_RUN_ID: usize = 64;

/// The slice a publisher of messages other than steps reserves first; larger ones grow it in
/// powers of two.
const INITIAL_SLICE: usize = 4096;

/// How long a cleanup waits for another process cleaning up the same dead node.
const CLEANUP_WAIT: Duration = Duration::from_millis(500);

/// One run's topics in this process, over iceoryx2 shared memory. One per process: create it
/// once and make every publisher and subscriber from it (it may be shared between threads;
/// each end stays in the thread that made it).
pub struct ShmTransport {
    node: Node<ipc::Service>,
    run_id: String,
    limits: ShmLimits,
}

/// What [`ShmTransport::remove_stale`] found of a run.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct StaleCleanup {
    /// Dead processes of the run whose shared memory was removed (with any dead process
    /// whose run is no longer known: see [`ShmTransport::remove_stale`]).
    pub removed: usize,
    /// Dead processes whose resources could not be removed (another process is removing
    /// them, or permissions).
    pub failed: usize,
    /// Process ids of the run's live processes: a run with this id is still going.
    pub alive: Vec<i32>,
    /// Services of any run left locked by a process killed as it made them
    /// (`stale::remove_locked_services`), removed.
    pub locked_services: usize,
}

impl ShmTransport {
    /// Joins run `run_id` as a process named `node_name` (its iceoryx2 node is named
    /// `pushgrasp/<run id>/<node name>`), opening topics with the run's `limits`. Removes what
    /// killed processes left first.
    pub fn new(run_id: &str, node_name: &str, limits: ShmLimits) -> Result<Self, TransportError> {
        check_run_id(run_id)?;
        let name = format!("{PREFIX}/{run_id}/{node_name}");
        let name = NodeName::new(&name).map_err(|e| TransportError::Setup {
            why: format!("{name:?} is not a valid iceoryx2 node name ({e})"),
        })?;
        let node = NodeBuilder::new()
            .name(&name)
            // The roles handle SIGINT and SIGTERM themselves.
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .config(&config()?)
            .create::<ipc::Service>()
            .map_err(|e| TransportError::Setup {
                why: format!("cannot create the iceoryx2 node {name}: {e}"),
            })?;
        node.try_cleanup_dead_nodes();
        Ok(Self {
            node,
            run_id: run_id.to_owned(),
            limits,
        })
    }

    pub fn run_id(&self) -> &str {
        &self.run_id
    }

    /// Removes the shared memory that dead processes of run `run_id` left behind (killed
    /// processes cannot remove their own), and says which of the run's processes are alive.
    /// The run's processes are those under `run_id` and under any id that extends it with
    /// `-<suffix>` (a launcher gives each launch of a run its own). A launcher calls it
    /// before it starts or resumes a run.
    ///
    /// A process killed while it wrote one of its node's files leaves it half-made, and
    /// iceoryx2 0.10's cleanup never removes such a file (`stale::finish_half_made`): it
    /// removes the node's details, then fails on the directory the file keeps, every time
    /// (and, without the details, warns that it takes its default config). A dead node's
    /// half-made files are marked finished first. A node already stuck that way, its
    /// details gone, is of no run anyone can name, so it is cleaned up whatever run asks, as
    /// iceoryx2 itself cleans up every dead node of any run when a node is created. So is
    /// a node killed before it had a monitor token, which iceoryx2 cannot find at all
    /// (`stale::remove_unmonitored`), and a service whose creator was killed before it
    /// wrote its static config (`stale::remove_locked_services`).
    pub fn remove_stale(run_id: &str) -> Result<StaleCleanup, TransportError> {
        check_run_id(run_id)?;
        let config = config()?;
        let mut dead = Vec::new();
        let mut listed = HashSet::new();
        let mut report = StaleCleanup::default();
        Node::<ipc::Service>::list(&config, |state| {
            listed.insert(state.node_id().value().to_string());
            match state {
                NodeState::Alive(view) => {
                    if let Some(details) = view.details()
                        && is_of_run(details.name().as_str(), run_id)
                    {
                        report.alive.push(details.process_id().value());
                    }
                }
                NodeState::Dead(view) => {
                    let run = view.details().as_ref().map(|d| d.name().to_string());
                    if run.is_none_or(|name| is_of_run(&name, run_id)) {
                        dead.push(view);
                    }
                }
                NodeState::Inaccessible(_) | NodeState::Undefined(_) => {}
            }
            CallbackProgression::Continue
        })
        .map_err(|e| TransportError::Setup {
            why: format!("cannot list the iceoryx2 nodes: {e}"),
        })?;
        for view in dead {
            stale::finish_half_made(&config, &view.id().value().to_string());
            match view.blocking_remove_stale_resources(CLEANUP_WAIT) {
                Ok(()) => report.removed += 1,
                Err(_) => report.failed += 1,
            }
        }
        report.removed += stale::remove_unmonitored(&config, &listed);
        report.locked_services = stale::remove_locked_services(&config);
        Ok(report)
    }

    /// What a failed port creation was, with the limit that may have refused it.
    fn ports(&self, kind: &str, admitted: usize) -> String {
        format!(
            "creating one of the {admitted} {kind} it admits in a run of {} processes",
            self.limits.processes()
        )
    }

    /// Opens (or creates) a topic's service with the settings every process uses.
    fn open_topic(
        &self,
        topic: Topic,
    ) -> Result<PortFactory<ipc::Service, [u8], ()>, TransportError> {
        let name = service_name(&self.run_id, topic);
        let name = ServiceName::new(&name)
            .map_err(|e| TransportError::iceoryx2(topic, "the service name", e))?;
        let lossless = topic.delivery() == Delivery::Lossless;
        self.node
            .service_builder(&name)
            .publish_subscribe::<[u8]>()
            .max_publishers(self.limits.publishers(topic))
            .max_subscribers(self.limits.subscribers(topic))
            .max_nodes(self.limits.nodes())
            .subscriber_max_buffer_size(self.limits.buffer(topic))
            // The message its sink is reading, and those it keeps back (see `kept`).
            .subscriber_max_borrowed_samples(kept(topic) + 1)
            .history_size(topic.history())
            .enable_safe_overflow(!lossless)
            .open_or_create()
            .map_err(|e| TransportError::Backend {
                topic: topic.name(),
                why: format!(
                    "cannot open the iceoryx2 service {name}, sized for a run of {} \
                     processes: {e} (more processes than that, a process of another \
                     pushgrasp build or with other limits in this run, or an earlier run's \
                     leftovers: remove stale resources or choose another run id)",
                    self.limits.processes()
                ),
            })
    }
}

/// Whether node `name` is a process of run `run_id`: named under the run's id, or under an
/// id that extends it with `-<suffix>` (one launch of the run).
fn is_of_run(name: &str, run_id: &str) -> bool {
    name.strip_prefix(PREFIX)
        .and_then(|rest| rest.strip_prefix('/'))
        .and_then(|rest| rest.strip_prefix(run_id))
        .is_some_and(|rest| rest.starts_with('/') || rest.starts_with('-'))
}

/// Messages a subscriber keeps back after reading them, before it returns them to their
/// publisher. A publisher writes its next message into the memory returned to it last; that
/// memory is still in the subscriber's cache if returned at once, and on another CPU every
/// line written must first be taken back from it. Keeping three 0.5 MB steps (more than a
/// core's 1 MB L2 cache here) sends the publisher to memory the subscriber's cache has let go:
/// one publisher to a subscriber on another CPU went from 2-11 GB/s to 24-31 (`bench
/// transport`, `iceoryx2_gbps_1_two_cpus`; keeping one: 17, two: 23-27).
///
/// Only while messages come in quick succession: a message kept longer than [`KEPT_AT_MOST`]
/// is returned, so one that comes alone goes to the memory the last one used, which the
/// caches still hold (p50 latency of lone 0.5 MB steps, a millisecond apart: 19-24 us, as
/// before; 53-68 when they too were kept).
fn kept(topic: Topic) -> usize {
    match topic {
        Topic::Steps => 3,
        _ => 0,
    }
}

/// How long a subscriber keeps a message back at most (see `kept`).
const KEPT_AT_MOST: Duration = Duration::from_micros(250);

/// The environment variable that gives this machine's iceoryx2 files another prefix than
/// iceoryx2's own (`iox2_`): processes under different prefixes share no memory. Several
/// simulated hosts on one machine each set their own (the tests do).
pub const SHM_PREFIX_VAR: &str = "PUSHGRASP_SHM_PREFIX";

/// iceoryx2's defaults (shared memory in /dev/shm, its files in /tmp/iceoryx2), never a
/// configuration file found on the machine: every process of a run must agree. Only the
/// prefix may be set, by [`SHM_PREFIX_VAR`].
fn config() -> Result<Config, TransportError> {
    let mut config = Config::default();
    if let Some(prefix) = std::env::var_os(SHM_PREFIX_VAR) {
        config.global.prefix =
            FileName::new(prefix.as_encoded_bytes()).map_err(|e| TransportError::Setup {
                why: format!("{SHM_PREFIX_VAR}={prefix:?} is not a file name prefix ({e:?})"),
            })?;
    }
    Ok(config)
}

fn service_name(run_id: &str, topic: Topic) -> String {
    format!("{PREFIX}/{run_id}/{}", topic.name())
}

fn check_run_id(run_id: &str) -> Result<(), TransportError> {
    let allowed = |c: char| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-');
    if run_id.is_empty() || run_id.len() > MAX_RUN_ID || !run_id.chars().all(allowed) {
        return Err(TransportError::Setup {
            why: format!(
                "run id {run_id:?} must be 1 to {MAX_RUN_ID} characters of A-Z, a-z, 0-9, \
                 '.', '_' and '-'"
            ),
        });
    }
    Ok(())
}

impl Transport for ShmTransport {
    fn publisher(&self, topic: Topic) -> Result<Box<dyn Publisher>, TransportError> {
        let service = self.open_topic(topic)?;
        let backpressure = match topic.delivery() {
            Delivery::Lossless => BackpressureStrategy::RetryUntilDelivered,
            // Unused: the service overwrites the oldest message instead.
            Delivery::Latest => BackpressureStrategy::DiscardData,
        };
        // Given up on, a message goes again to every reader: only where there is one reader
        // does that not send it twice.
        let patience = (topic.fan() != Fan::OneToMany).then_some(WAITING_EVERY);
        let (allocation, first_slice) = self.limits.memory(topic);
        let publisher = service
            .publisher_builder()
            .backpressure_strategy(backpressure)
            .set_backpressure_handler(move |info: &BackpressureInfo| wait_for_room(info, patience))
            .allocation_strategy(allocation)
            .initial_max_slice_len(first_slice)
            .create()
            .map_err(|e| {
                let admitted = self.limits.publishers(topic);
                TransportError::iceoryx2(topic, &self.ports("publishers", admitted), e)
            })?;
        Ok(Box::new(ShmPublisher {
            topic,
            publisher,
            service,
        }))
    }

    fn subscriber(&self, topic: Topic) -> Result<Box<dyn Subscriber>, TransportError> {
        let service = self.open_topic(topic)?;
        let subscriber = service.subscriber_builder().create().map_err(|e| {
            let admitted = self.limits.subscribers(topic);
            TransportError::iceoryx2(topic, &self.ports("subscribers", admitted), e)
        })?;
        Ok(Box::new(ShmSubscriber {
            topic,
            subscriber,
            kept: VecDeque::with_capacity(kept(topic)),
            _service: service,
        }))
    }
}

/// A message read in place, its memory the publisher's until dropped.
type ShmSample = Sample<ipc::Service, [u8], ()>;

struct ShmSubscriber {
    topic: Topic,
    subscriber: IoxSubscriber<ipc::Service, [u8], ()>,
    /// The last messages read and when, oldest first (see `kept`).
    kept: VecDeque<(Instant, ShmSample)>,
    _service: PortFactory<ipc::Service, [u8], ()>,
}

impl ShmSubscriber {
    /// Returns to their publishers the messages kept longest, beyond `kept(topic)` or
    /// [`KEPT_AT_MOST`].
    fn return_kept(&mut self) {
        if self.kept.is_empty() {
            return;
        }
        let now = Instant::now();
        while self.kept.front().is_some_and(|(read, _)| {
            self.kept.len() > kept(self.topic) || now - *read > KEPT_AT_MOST
        }) {
            self.kept.pop_front();
        }
    }
}

impl Subscriber for ShmSubscriber {
    fn refresh(&mut self) -> Result<(), TransportError> {
        self.subscriber
            .update_connections()
            .map_err(|e| TransportError::iceoryx2(self.topic, "connecting to new publishers", e))
    }

    fn receive(&mut self, sink: &mut dyn FnMut(&[u8])) -> Result<bool, TransportError> {
        match self
            .subscriber
            .receive()
            .map_err(|e| TransportError::iceoryx2(self.topic, "receiving", e))?
        {
            Some(sample) => {
                sink(sample.payload());
                if kept(self.topic) > 0 {
                    self.kept.push_back((Instant::now(), sample));
                }
                self.return_kept();
                Ok(true)
            }
            None => {
                self.return_kept();
                Ok(false)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_runs_processes_are_those_of_its_id_and_of_its_launches() {
        let run = "stage1-00ff";
        for ours in [
            "pushgrasp/stage1-00ff/launcher",
            "pushgrasp/stage1-00ff-1a2b/actor-0-0",
        ] {
            assert!(is_of_run(ours, run), "{ours}");
        }
        for theirs in [
            "pushgrasp/stage1-00ffe/launcher",
            "pushgrasp/stage1-00f/launcher",
            "pushgrasp/stage1-00ff",
            "other/stage1-00ff/launcher",
        ] {
            assert!(!is_of_run(theirs, run), "{theirs}");
        }
    }

    #[test]
    fn run_ids_are_checked() {
        for bad in ["", "a/b", "a b", "ü", &"x".repeat(MAX_RUN_ID + 1)] {
            let err = ShmTransport::remove_stale(bad).unwrap_err();
            assert!(err.to_string().contains("run id"), "{err}");
        }
        for good in ["run-1", "2026.01.02_a", &"x".repeat(MAX_RUN_ID)] {
            check_run_id(good).unwrap();
        }
    }

    #[test]
    fn one_transport_serves_every_thread() {
        fn shared<T: Send + Sync>() {}
        shared::<ShmTransport>();
    }

    #[test]
    fn service_names_carry_the_run() {
        assert_eq!(service_name("r1", Topic::Steps), "pushgrasp/r1/steps");
        for topic in Topic::ALL {
            ServiceName::new(&service_name(&"x".repeat(MAX_RUN_ID), topic)).unwrap();
        }
    }
}
