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

use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result, ensure};
use clap::{Args, ValueEnum};
use serde::Serialize;
use wire::{ShmLimits, ShmTransport, Topic, Transport};

use super::{median, print_figures};

/// The limits the bench's processes (up to 4 publishers and a subscriber) open its topics
/// with, for its messages of `--size` bytes.
fn limits(args: &TransportBenchArgs) -> ShmLimits {
    ShmLimits::for_run(5, args.size)
}

#[derive(Args)]
pub struct TransportBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Messages of each bandwidth measurement, shared among its publishers.
    #[arg(long, default_value_t = 2048)]
    messages: usize,
    /// Bytes in a message.
    #[arg(long, default_value_t = 512 * 1024)]
    size: usize,
    /// Repetitions of each bandwidth figure (medians are reported).
    #[arg(long, default_value_t = 5)]
    reps: usize,
    /// Messages timed for the latency.
    #[arg(long, default_value_t = 500)]
    latency_messages: usize,
    /// Inside the bench: publish as process `index` over this transport.
    #[arg(long, hide = true)]
    publisher: Option<Via>,
    #[arg(long, hide = true, default_value_t = 0)]
    index: u32,
    /// Inside the bench: the run id (shared memory) or the socket path.
    #[arg(long, hide = true, default_value = "")]
    to: String,
    /// Inside the bench: the CPU a publishing process runs on.
    #[arg(long, hide = true)]
    cpu: Option<usize>,
}

/// How a publishing process sends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Via {
    Iceoryx2,
    UnixSocket,
    /// iceoryx2, one message a millisecond, each carrying the time it was sent.
    Iceoryx2Latency,
}

impl Via {
    fn arg(self) -> &'static str {
        match self {
            Via::Iceoryx2 => "iceoryx2",
            Via::UnixSocket => "unix-socket",
            Via::Iceoryx2Latency => "iceoryx2-latency",
        }
    }
}

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

fn nanos_now() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// Removes a file when dropped (the socket, whatever happens).
struct RemoveOnDrop(PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The publishing processes of one measurement; killed if still running when dropped.
struct Publishers {
    children: Vec<(Child, BufReader<ChildStdout>)>,
}

impl Publishers {
    fn start(
        via: Via,
        to: &str,
        count: usize,
        messages: usize,
        size: usize,
        cpu: Option<usize>,
    ) -> Result<Self> {
        let exe = std::env::current_exe().context("finding this program")?;
        let mut publishers = Self {
            children: Vec::new(),
        };
        for index in 0..count {
            let mut command = Command::new(&exe);
            command
                .args(["bench", "transport", "--publisher", via.arg(), "--to", to])
                .args(["--index", &index.to_string()])
                .args(["--messages", &messages.to_string()])
                .args(["--size", &size.to_string()]);
            if let Some(cpu) = cpu {
                command.args(["--cpu", &cpu.to_string()]);
            }
            let mut child = command
                .stdin(Stdio::piped())
                .stdout(Stdio::piped())
                .spawn()
                .context("starting a publishing process")?;
            let stdout = BufReader::new(child.stdout.take().expect("piped"));
            publishers.children.push((child, stdout));
        }
        Ok(publishers)
    }

    /// Waits until every publisher says it is ready.
    fn wait_ready(&mut self) -> Result<()> {
        for (_, stdout) in &mut self.children {
            let mut line = String::new();
            stdout.read_line(&mut line)?;
            ensure!(
                line.trim() == "ready",
                "a publishing process failed to start"
            );
        }
        Ok(())
    }

    fn go(&mut self) -> Result<()> {
        for (child, _) in &mut self.children {
            child.stdin.as_mut().expect("piped").write_all(b"go\n")?;
        }
        Ok(())
    }

    /// Closes their stdin (the sign to exit) and waits for them.
    fn finish(mut self) -> Result<()> {
        for (mut child, _) in self.children.drain(..) {
            drop(child.stdin.take());
            let status = child.wait()?;
            ensure!(status.success(), "a publishing process failed: {status}");
        }
        Ok(())
    }
}

impl Drop for Publishers {
    fn drop(&mut self) {
        for (child, _) in &mut self.children {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// What the iceoryx2 subscriber does with each message.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Use {
    /// Reads every byte in place and checks the contents.
    Read,
    /// Copies the message out (as a decoder would), then reads and checks the copy.
    Copy,
    /// Reads only the sender and number: the transport's own cost, the bytes staying where
    /// the publisher wrote them.
    Header,
}

/// Which CPUs a measurement's subscriber and publishers run on.
#[derive(Clone, Copy)]
enum Cpus {
    /// Wherever the scheduler puts them.
    Any,
    Pinned {
        subscriber: usize,
        publisher: usize,
    },
}

/// Runs `work` on a thread that runs on `cpu` alone.
fn on_cpu<T: Send>(cpu: usize, work: impl FnOnce() -> Result<T> + Send) -> Result<T> {
    std::thread::scope(|scope| {
        scope
            .spawn(|| {
                pin_to(cpu)?;
                work()
            })
            .join()
            .expect("a pinned bench thread panicked")
    })
}

fn pin_to(cpu: usize) -> Result<()> {
    ensure!(
        core_affinity::set_for_current(core_affinity::CoreId { id: cpu }),
        "cannot run on CPU {cpu}"
    );
    Ok(())
}

/// Time for `publishers` processes to send `messages` each to one iceoryx2 subscriber, which
/// checks each message's sender and number and uses it as `how` says.
fn shm_bandwidth(
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

/// Time for `publishers` processes to send `messages` each over their own Unix socket to one
/// receiver, which reads every length-prefixed message into a buffer and reads every byte of
/// it, as the iceoryx2 subscriber does in place (one thread, polling the sockets in turn, as
/// the iceoryx2 subscriber polls its publishers).
fn socket_bandwidth(
    args: &TransportBenchArgs,
    socket: &Path,
    publishers: usize,
    messages: usize,
) -> Result<Duration> {
    let _ = std::fs::remove_file(socket);
    let listener = UnixListener::bind(socket).context("binding the Unix socket")?;
    let to = socket.to_str().context("the socket path is not UTF-8")?;
    let mut children =
        Publishers::start(Via::UnixSocket, to, publishers, messages, args.size, None)?;
    listener.set_nonblocking(true)?;
    let mut streams: Vec<Frames> = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    while streams.len() < publishers {
        match listener.accept() {
            Ok((stream, _)) => {
                stream.set_nonblocking(true)?;
                streams.push(Frames::new(stream, args.size));
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                ensure!(
                    Instant::now() < deadline,
                    "the publishing processes did not connect"
                );
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(e) => return Err(e.into()),
        }
    }
    children.wait_ready()?;
    let total = messages * publishers;
    let mut received = 0;
    let mut sums = Vec::with_capacity(total);
    let start = Instant::now();
    children.go()?;
    while received < total {
        let mut progress = false;
        for stream in &mut streams {
            let (messages, read) = stream.read_available(&mut |message| {
                sums.push((header(message).0, checksum(message)));
            })?;
            received += messages;
            progress |= read;
        }
        if !progress {
            std::thread::yield_now();
        }
    }
    let time = start.elapsed();
    let expected: Vec<u64> = (0..publishers)
        .map(|index| checksum(&message_of(index, args.size)))
        .collect();
    let wrong = sums
        .iter()
        .filter(|&&(index, sum)| expected.get(index) != Some(&sum))
        .count();
    ensure!(wrong == 0, "{wrong} messages arrived changed");
    children.finish()?;
    drop(listener);
    let _ = std::fs::remove_file(socket);
    Ok(time)
}

/// Length-prefixed messages arriving on a non-blocking Unix socket.
struct Frames {
    stream: UnixStream,
    len: [u8; 4],
    len_read: usize,
    message: Vec<u8>,
    message_read: usize,
}

impl Frames {
    fn new(stream: UnixStream, size: usize) -> Self {
        Self {
            stream,
            len: [0; 4],
            len_read: 0,
            message: vec![0; size],
            message_read: 0,
        }
    }

    /// Reads what the socket holds, handing each complete message to `sink`: (messages
    /// completed, whether any byte came).
    fn read_available(&mut self, sink: &mut dyn FnMut(&[u8])) -> Result<(usize, bool)> {
        let (mut messages, mut any) = (0, false);
        loop {
            let read = if self.len_read < 4 {
                self.stream.read(&mut self.len[self.len_read..])
            } else {
                let len = u32::from_le_bytes(self.len) as usize;
                ensure!(len == self.message.len(), "a {len}-byte message arrived");
                self.stream.read(&mut self.message[self.message_read..])
            };
            let n = match read {
                Ok(0) => return Ok((messages, any)),
                Ok(n) => n,
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok((messages, any)),
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(e.into()),
            };
            any = true;
            if self.len_read < 4 {
                self.len_read += n;
            } else {
                self.message_read += n;
                if self.message_read == self.message.len() {
                    sink(&self.message);
                    messages += 1;
                    self.len_read = 0;
                    self.message_read = 0;
                }
            }
        }
    }
}

/// Rate of copying `size`-byte buffers, `messages` times per repetition, from `sources`
/// buffers in turn into one: with one source, the floor of any transport that hands the
/// receiver its own copy (the source in cache); with many, the copy of data in no cache.
fn memcpy_gbps(size: usize, messages: usize, reps: usize, sources: usize) -> f64 {
    let sources: Vec<Vec<u8>> = (0..sources.max(1)).map(|k| vec![k as u8; size]).collect();
    let mut target = vec![0u8; size];
    let runs = (0..reps)
        .map(|_| {
            let start = Instant::now();
            for source in sources.iter().cycle().take(messages) {
                target.copy_from_slice(std::hint::black_box(source));
                std::hint::black_box(&mut target);
            }
            (messages * size) as f64 / start.elapsed().as_secs_f64() / 1e9
        })
        .collect();
    median(runs)
}

/// Rate of handing `messages` messages of `size` bytes from a thread on CPU `writer` to one on
/// CPU `reader` through plain memory, the work of the one-publisher measurement without a
/// transport: the writer copies the message into the oldest free of as many buffers as the
/// steps topic holds (as a publisher copies into shared memory), the reader reads every byte
/// of it (the same checksum) and hands the buffer back.
fn handoff_gbps(
    size: usize,
    messages: usize,
    reps: usize,
    reader: usize,
    writer: usize,
) -> Result<f64> {
    use std::sync::mpsc::sync_channel;
    let buffers = Topic::Steps.buffer();
    let message = message_of(0, size);
    let expected = checksum(&message);
    let mut runs = Vec::with_capacity(reps);
    for _ in 0..reps {
        let (full_tx, full_rx) = sync_channel::<Vec<u8>>(buffers);
        let (empty_tx, empty_rx) = sync_channel::<Vec<u8>>(buffers);
        for _ in 0..buffers {
            empty_tx.send(vec![0; size])?;
        }
        let message = &message;
        let time = on_cpu(reader, move || {
            std::thread::scope(|scope| {
                let writing = scope.spawn(move || -> Result<()> {
                    pin_to(writer)?;
                    for mut buffer in empty_rx.iter().take(messages) {
                        buffer.copy_from_slice(message);
                        full_tx.send(buffer)?;
                    }
                    Ok(())
                });
                let start = Instant::now();
                let mut read = 0;
                for buffer in full_rx.iter().take(messages) {
                    ensure!(checksum(&buffer) == expected, "a buffer arrived changed");
                    read += 1;
                    // The writer stops taking buffers after the last message.
                    let _ = empty_tx.send(buffer);
                }
                let time = start.elapsed();
                writing.join().expect("the writing thread panicked")?;
                ensure!(read == messages, "{read} of {messages} buffers arrived");
                Ok(time)
            })
        })?;
        runs.push((messages * size) as f64 / time.as_secs_f64() / 1e9);
    }
    Ok(median(runs))
}

/// Latency of iceoryx2 for messages of `--size` bytes, one a millisecond (so none waits for
/// another): from the publisher reading the clock just before it sends (the copy into shared
/// memory included) to the subscriber, spinning on its receive, holding the message. The
/// clock is the system's real-time clock, which both processes read. (p50, p99) in us.
fn shm_latency(args: &TransportBenchArgs, run: &str) -> Result<(f64, f64)> {
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

/// The message publisher `index` sends, before its first 16 bytes get its number (and, for
/// the latency, the time).
fn message_of(index: usize, size: usize) -> Vec<u8> {
    (0..size).map(|i| (i * 131 + index) as u8).collect()
}

/// Reads every byte after the first 16 (what a receiver that uses the message does): the
/// wrapping sum of its 8-byte words.
fn checksum(bytes: &[u8]) -> u64 {
    bytes[16..]
        .chunks_exact(8)
        .map(|w| u64::from_le_bytes(w.try_into().expect("8 bytes")))
        .fold(0, u64::wrapping_add)
}

/// A message's publisher index and number (its first 8 bytes).
fn header(bytes: &[u8]) -> (usize, u64) {
    let word = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes"));
    ((word >> 48) as usize, word & ((1 << 48) - 1))
}

/// A publishing process: connects, says "ready", sends on "go", then waits for its stdin to
/// close (so the subscriber has read everything before its publisher goes).
fn publish(via: Via, args: &TransportBenchArgs) -> Result<()> {
    let mut message = message_of(args.index as usize, args.size);
    let stamp = |message: &mut [u8], seq: u64| {
        let word = (u64::from(args.index) << 48) | seq;
        message[..8].copy_from_slice(&word.to_le_bytes());
    };
    if let Some(cpu) = args.cpu {
        pin_to(cpu)?;
    }
    let mut stdin = std::io::stdin().lock();
    let ready_then_go = |stdin: &mut std::io::StdinLock| -> Result<()> {
        println!("ready");
        std::io::stdout().flush()?;
        let mut go = String::new();
        stdin.read_line(&mut go)?;
        ensure!(go.trim() == "go", "the bench did not say go");
        Ok(())
    };
    match via {
        Via::Iceoryx2 | Via::Iceoryx2Latency => {
            let transport = ShmTransport::new(
                &args.to,
                &format!("bench-publisher-{}", args.index),
                limits(args),
            )?;
            let mut publisher = transport.publisher(Topic::Steps)?;
            ready_then_go(&mut stdin)?;
            for seq in 0..args.messages as u64 {
                stamp(&mut message, seq);
                if via == Via::Iceoryx2Latency {
                    std::thread::sleep(Duration::from_millis(1));
                    message[8..16].copy_from_slice(&nanos_now().to_le_bytes());
                }
                publisher.send(&message)?;
            }
            // Keep the publisher until the subscriber is done.
            std::io::copy(&mut stdin, &mut std::io::sink())?;
        }
        Via::UnixSocket => {
            let mut stream = UnixStream::connect(&args.to)
                .with_context(|| format!("connecting to {}", args.to))?;
            ready_then_go(&mut stdin)?;
            let len = u32::try_from(args.size)?.to_le_bytes();
            for seq in 0..args.messages as u64 {
                stamp(&mut message, seq);
                stream.write_all(&len)?;
                stream.write_all(&message)?;
            }
            stream.flush()?;
            std::io::copy(&mut stdin, &mut std::io::sink())?;
        }
    }
    Ok(())
}
