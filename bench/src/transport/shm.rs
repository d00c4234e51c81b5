//! iceoryx2 shared memory measured: the bandwidth from 1, 2 and 4 publishing processes to
//! one subscriber, and the latency of one message a millisecond.

use std::time::{Duration, Instant};

use anyhow::{Result, ensure};
use wire::{ShmTransport, Topic, Transport};

use super::args::{TransportBenchArgs, Via, limits};
use super::cpus::{Cpus, on_cpu};
use super::message::{checksum, header, message_of, nanos_now};
use super::publishers::Publishers;
use crate::median;

/// What the iceoryx2 subscriber does with each message.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Use {
    /// Reads every byte in place and checks the contents.
    Read,
    /// Copies the message out (as a decoder would), then reads and checks the copy.
    Copy,
    /// Reads only the sender and number: the transport's own cost, the bytes staying where
    /// the publisher wrote them.
    Header,
}

/// Time for `publishers` processes to send `messages` each to one iceoryx2 subscriber, which
/// checks each message's sender and number and uses it as `how` says.
pub(super) fn shm_bandwidth(
    args: &TransportBenchArgs,
    run: &str,
    publishers: usize,
    messages: usize,
    how: Use,
    cpus: Cpus,
) -> Result<Duration> {
    if let Cpus::Pinned {
        subscriber,
        publisher,
    } = cpus
    {
        return on_cpu(subscriber, || {
            shm_receive(args, run, publishers, messages, how, Some(publisher))
        });
    }
    shm_receive(args, run, publishers, messages, how, None)
}

/// [`shm_bandwidth`] on the calling thread, the publishers on `publisher_cpu` if given.
fn shm_receive(
    args: &TransportBenchArgs,
    run: &str,
    publishers: usize,
    messages: usize,
    how: Use,
    publisher_cpu: Option<usize>,
) -> Result<Duration> {
    let time = {
        let transport = ShmTransport::new(run, "bench-subscriber", limits(args))?;
        let mut subscriber = transport.subscriber(Topic::Steps)?;
        let mut children = Publishers::start(
            Via::Iceoryx2,
            run,
            publishers,
            messages,
            args.size,
            publisher_cpu,
        )?;
        children.wait_ready()?;
        // Connects to the publishers.
        subscriber.receive(&mut |_| {})?;
        let mut next = vec![0u64; publishers];
        let expected: Vec<u64> = (0..publishers)
            .map(|index| checksum(&message_of(index, args.size)))
            .collect();
        let mut copied = vec![0u8; args.size];
        let mut wrong = 0;
        let total = messages * publishers;
        let mut received = 0;
        let start = Instant::now();
        children.go()?;
        while received < total {
            let got = subscriber.receive(&mut |bytes| {
                let (index, seq) = header(bytes);
                if bytes.len() != copied.len() || next.get(index) != Some(&seq) {
                    wrong += 1;
                    return;
                }
                next[index] += 1;
                let sum = match how {
                    Use::Read => checksum(bytes),
                    Use::Copy => {
                        copied.copy_from_slice(bytes);
                        checksum(&copied)
                    }
                    Use::Header => return,
                };
                wrong += usize::from(sum != expected[index]);
            })?;
            received += usize::from(got);
            if !got {
                std::thread::yield_now();
            }
        }
        let time = start.elapsed();
        ensure!(
            wrong == 0,
            "{wrong} messages arrived out of order or resized"
        );
        std::hint::black_box(&copied);
        children.finish()?;
        time
    };
    ShmTransport::remove_stale(run)?;
    Ok(time)
}

/// Latency of iceoryx2 for messages of `--size` bytes, one a millisecond (so none waits for
/// another): from the publisher reading the clock just before it sends (the copy into shared
/// memory included) to the subscriber, spinning on its receive, holding the message. The
/// clock is the system's real-time clock, which both processes read. (p50, p99) in us.
pub(super) fn shm_latency(args: &TransportBenchArgs, run: &str) -> Result<(f64, f64)> {
    let messages = args.latency_messages.max(1);
    let mut latencies = Vec::with_capacity(messages);
    {
        let transport = ShmTransport::new(run, "bench-subscriber", limits(args))?;
        let mut subscriber = transport.subscriber(Topic::Steps)?;
        let mut child = Publishers::start(Via::Iceoryx2Latency, run, 1, messages, args.size, None)?;
        child.wait_ready()?;
        subscriber.receive(&mut |_| {})?;
        child.go()?;
        while latencies.len() < messages {
            subscriber.receive(&mut |bytes| {
                let now = nanos_now();
                let sent = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes"));
                latencies.push(now.saturating_sub(sent) as f64 / 1e3);
            })?;
        }
        child.finish()?;
    }
    ShmTransport::remove_stale(run)?;
    latencies.sort_by(f64::total_cmp);
    let p99 = latencies[(latencies.len() * 99 / 100).min(latencies.len() - 1)];
    Ok((median(latencies), p99))
}
