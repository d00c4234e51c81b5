//! What `bench transport` is asked: its figures' sizes, and, inside the bench, what a
//! publishing process sends and how.

use clap::{Args, ValueEnum};
use wire::ShmLimits;

/// The limits the bench's processes (up to 4 publishers and a subscriber) open its topics
/// with, for its messages of `--size` bytes.
pub(super) fn limits(args: &TransportBenchArgs) -> ShmLimits {
    ShmLimits::for_run(5, args.size)
}

#[derive(Args)]
pub struct TransportBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub(super) json: bool,
    /// Messages of each bandwidth measurement, shared among its publishers.
    #[arg(long, default_value_t = 2048)]
    pub(super) messages: usize,
    /// Bytes in a message.
    #[arg(long, default_value_t = 512 * 1024)]
    pub(super) size: usize,
    /// Repetitions of each bandwidth figure (medians are reported).
    #[arg(long, default_value_t = 5)]
    pub(super) reps: usize,
    /// Messages timed for the latency.
    #[arg(long, default_value_t = 500)]
    pub(super) latency_messages: usize,
    /// Inside the bench: publish as process `index` over this transport.
    #[arg(long, hide = true)]
    pub(super) publisher: Option<Via>,
    #[arg(long, hide = true, default_value_t = 0)]
    pub(super) index: u32,
    /// Inside the bench: the run id (shared memory) or the socket path.
    #[arg(long, hide = true, default_value = "")]
    pub(super) to: String,
    /// Inside the bench: the CPU a publishing process runs on.
    #[arg(long, hide = true)]
    pub(super) cpu: Option<usize>,
}

/// How a publishing process sends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub(super) enum Via {
    Iceoryx2,
    UnixSocket,
    /// iceoryx2, one message a millisecond, each carrying the time it was sent.
    Iceoryx2Latency,
}

impl Via {
    pub(super) fn arg(self) -> &'static str {
        match self {
            Via::Iceoryx2 => "iceoryx2",
            Via::UnixSocket => "unix-socket",
            Via::Iceoryx2Latency => "iceoryx2-latency",
        }
    }
}
