//! `pushgrasp bench transport`: 0.5 MB steps from 1, 2 and 4 publishing processes to one
//! subscriber through iceoryx2 shared memory (the runtime's `wire::ShmTransport`, steps topic),
//! the same bytes over Unix sockets, and a memcpy of them: all measured in one run.
//!
//! The publishing processes are this program again (`bench transport --publisher ...`): they
//! connect, say they are ready, and send when the bench writes "go" to them, so process start
//! is not timed. Bandwidth is the bytes of every message over the time from "go" to the last
//! message received; GB are 10^9 bytes. Every receiver reads every byte of every message (a
//! checksum, checked): the iceoryx2 subscriber where the publisher wrote it, the socket
//! receiver in the buffer it read it into. `iceoryx2_header_only_gbps_1` and
//! `iceoryx2_copied_gbps_1` bound it: a subscriber that reads only the message number, and one
//! that copies each message out first.
//!
//! Where the scheduler puts one publisher and its subscriber moves that figure: on one CPU they
//! take turns, on two every line the subscriber reads comes from the other CPU's cache. So one
//! publisher is measured again with both processes pinned to one CPU and to two, beside the
//! same work done by two threads through plain memory (`handoff_gbps_*`): what those CPUs give
//! without a transport.

mod args;
mod cpus;
mod floors;
mod message;
mod publishers;
mod shm;
mod socket;

use anyhow::{Context, Result, ensure};
use serde::Serialize;

use super::{median, print_figures};
pub use args::TransportBenchArgs;
use cpus::Cpus;
use floors::{handoff_gbps, memcpy_gbps};
use message::nanos_now;
use publishers::publish;
use shm::{Use, shm_bandwidth, shm_latency};
use socket::{RemoveOnDrop, socket_bandwidth};

#[derive(Serialize)]
struct TransportFigures {
    message_bytes: usize,
    /// Messages of each bandwidth measurement.
    messages: usize,
    /// GB/s from 1, 2 and 4 processes.
    iceoryx2_gbps_1: f64,
    unix_socket_gbps_1: f64,
    iceoryx2_gbps_2: f64,
    unix_socket_gbps_2: f64,
    iceoryx2_gbps_4: f64,
    unix_socket_gbps_4: f64,
    /// Copying one buffer into another, both in cache.
    memcpy_gbps: f64,
    /// One publisher, the subscriber copying every message out (as a decoder would).
    iceoryx2_copied_gbps_1: f64,
    /// One publisher, the subscriber reading only each message's number.
    iceoryx2_header_only_gbps_1: f64,
    /// memcpy from sources that are in no cache.
    memcpy_uncached_gbps: f64,
    /// One publisher, both processes pinned to one CPU, and to two (null on one CPU).
    iceoryx2_gbps_1_same_cpu: f64,
    iceoryx2_gbps_1_two_cpus: Option<f64>,
    /// The same bytes handed between two threads through plain memory, on one CPU and two.
    handoff_gbps_same_cpu: f64,
    handoff_gbps_two_cpus: Option<f64>,
    iceoryx2_over_unix_socket_1: f64,
    iceoryx2_over_unix_socket_2: f64,
    iceoryx2_over_unix_socket_4: f64,
    iceoryx2_over_memcpy_1: f64,
    iceoryx2_over_memcpy_2: f64,
    iceoryx2_over_memcpy_4: f64,
    iceoryx2_p50_latency_us: f64,
    iceoryx2_p99_latency_us: f64,
}

pub fn bench_transport(args: &TransportBenchArgs) -> Result<()> {
    if let Some(via) = args.publisher {
        return publish(via, args);
    }
    ensure!(args.size >= 16, "--size must be at least 16 bytes");
    let reps = args.reps.max(1);
    let tag = format!(
        "bench-{}-{}",
        std::process::id(),
        nanos_now() % 1_000_000_000
    );
    let socket = std::env::temp_dir().join(format!("pushgrasp-{tag}.sock"));
    let _socket_file = RemoveOnDrop(socket.clone());

    let mut iceoryx2 = [0.0; 3];
    let mut unix_socket = [0.0; 3];
    for (k, publishers) in [1, 2, 4].into_iter().enumerate() {
        let messages = (args.messages / publishers).max(1);
        let bytes = (messages * publishers * args.size) as f64;
        let mut shm_runs = Vec::new();
        let mut socket_runs = Vec::new();
        for rep in 0..reps {
            let run = format!("{tag}-{publishers}-{rep}");
            let time = shm_bandwidth(args, &run, publishers, messages, Use::Read, Cpus::Any)?;
            shm_runs.push(bytes / time.as_secs_f64() / 1e9);
            let time = socket_bandwidth(args, &socket, publishers, messages)?;
            socket_runs.push(bytes / time.as_secs_f64() / 1e9);
        }
        iceoryx2[k] = median(shm_runs);
        unix_socket[k] = median(socket_runs);
    }
    let one_publisher = |how: Use, cpus: Cpus, name: &str| -> Result<f64> {
        let mut runs = Vec::new();
        for rep in 0..reps {
            let run = format!("{tag}-{name}-{rep}");
            let time = shm_bandwidth(args, &run, 1, args.messages, how, cpus)?;
            runs.push((args.messages * args.size) as f64 / time.as_secs_f64() / 1e9);
        }
        Ok(median(runs))
    };
    let copied = one_publisher(Use::Copy, Cpus::Any, "copied")?;
    let header_only = one_publisher(Use::Header, Cpus::Any, "header")?;
    let cpus: Vec<usize> = core_affinity::get_core_ids()
        .context("reading the CPUs this bench may use")?
        .iter()
        .map(|cpu| cpu.id)
        .collect();
    let first = *cpus.first().context("this bench may use no CPU")?;
    let second = cpus.get(1).copied();
    let pinned = |publisher| Cpus::Pinned {
        subscriber: first,
        publisher,
    };
    let same_cpu = one_publisher(Use::Read, pinned(first), "same-cpu")?;
    let two_cpus = second
        .map(|second| one_publisher(Use::Read, pinned(second), "two-cpus"))
        .transpose()?;
    let handoff_same_cpu = handoff_gbps(args.size, args.messages, reps, first, first)?;
    let handoff_two_cpus = second
        .map(|second| handoff_gbps(args.size, args.messages, reps, first, second))
        .transpose()?;
    let memcpy = memcpy_gbps(args.size, args.messages, reps, 1);
    // Sources spread over 256 MB: far more than any cache holds.
    let memcpy_uncached = memcpy_gbps(args.size, args.messages, reps, (256 << 20) / args.size);
    let (p50, p99) = shm_latency(args, &format!("{tag}-latency"))?;

    let figures = TransportFigures {
        message_bytes: args.size,
        messages: args.messages,
        iceoryx2_gbps_1: iceoryx2[0],
        unix_socket_gbps_1: unix_socket[0],
        iceoryx2_gbps_2: iceoryx2[1],
        unix_socket_gbps_2: unix_socket[1],
        iceoryx2_gbps_4: iceoryx2[2],
        unix_socket_gbps_4: unix_socket[2],
        memcpy_gbps: memcpy,
        iceoryx2_copied_gbps_1: copied,
        iceoryx2_header_only_gbps_1: header_only,
        memcpy_uncached_gbps: memcpy_uncached,
        iceoryx2_gbps_1_same_cpu: same_cpu,
        iceoryx2_gbps_1_two_cpus: two_cpus,
        handoff_gbps_same_cpu: handoff_same_cpu,
        handoff_gbps_two_cpus: handoff_two_cpus,
        iceoryx2_over_unix_socket_1: iceoryx2[0] / unix_socket[0],
        iceoryx2_over_unix_socket_2: iceoryx2[1] / unix_socket[1],
        iceoryx2_over_unix_socket_4: iceoryx2[2] / unix_socket[2],
        iceoryx2_over_memcpy_1: iceoryx2[0] / memcpy,
        iceoryx2_over_memcpy_2: iceoryx2[1] / memcpy,
        iceoryx2_over_memcpy_4: iceoryx2[2] / memcpy,
        iceoryx2_p50_latency_us: p50,
        iceoryx2_p99_latency_us: p99,
    };
    print_figures(&serde_json::to_value(&figures)?, args.json)
}
