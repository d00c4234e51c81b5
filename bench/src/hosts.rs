//! `pushgrasp bench hosts`: the link between hosts. Real-size steps (rendered scenes at the
//! run config's resolution, encoded as the wire sends them) from a joined host's Zenoh session
//! to the central one over loopback, beside a plain TCP socket moving the same bytes, in the
//! same run: packed into parcels as the bridge sends them, and one step per message as they
//! lie in shared memory; what packing costs; and one publication of the nets' weights reaching
//! 4 joined hosts.
//!
//! Both receivers read every byte of every message (a checksum, checked), and both senders
//! copy each message once from where it lies (as the bridge copies a step out of shared
//! memory). MB are 10^6 bytes on the wire.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, ensure};
use bridge::parcel::{self, Packer, Parcel};
use bridge::zenoh::Wait;
use bridge::{Endpoint, Keys, RunSecret, Stream, link, session};
use clap::Args;
use serde::Serialize;
use sim::SimConfig;
use wire::{Message, Origin, Step};

use super::{median, print_figures, rendered_scene};

#[derive(Args)]
pub struct HostsBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Steps of each throughput measurement (enough that one lasts a good fraction of a
    /// second: a few thousand pass in milliseconds and time mostly the start).
    #[arg(long, default_value_t = 30_000)]
    steps: usize,
    /// Repetitions of each throughput figure (medians are reported).
    #[arg(long, default_value_t = 3)]
    reps: usize,
    /// Weight publications timed.
    #[arg(long, default_value_t = 20)]
    publications: usize,
    /// The run config whose resolution and nets are measured.
    #[arg(long, default_value = "configs/stage1.toml")]
    config: std::path::PathBuf,
}

/// Joined hosts the weights reach.
const FANOUT_HOSTS: usize = 4;
const RUN_ID: &str = "bench-hosts";

#[derive(Serialize)]
struct HostsFigures {
    side: usize,
    /// A step's wire encoding, mean over the scenes.
    step_bytes: usize,
    steps: usize,
    steps_per_parcel: usize,
    parcel_bytes: usize,
    compression_ratio: f64,
    /// Packing (compressing) and unpacking a parcel, per step it holds.
    pack_us_per_step: f64,
    unpack_us_per_step: f64,
    /// Steps/s in parcels, the bytes the bridge sends.
    zenoh_steps_per_s: f64,
    tcp_steps_per_s: f64,
    zenoh_over_tcp: f64,
    zenoh_mb_per_s: f64,
    tcp_mb_per_s: f64,
    /// One uncompressed step per message.
    zenoh_raw_steps_per_s: f64,
    tcp_raw_steps_per_s: f64,
    zenoh_raw_over_tcp: f64,
    /// The slowest of packing, the link and unpacking: the bridge's pace on this machine.
    bridge_steps_per_s: f64,
    weights_bytes: usize,
    hosts: usize,
    /// From the central host's publication to the last of the hosts receiving it.
    weights_fanout_ms: f64,
    weights_fanout_max_ms: f64,
}

/// Scenes the steps of a parcel come from (each parcel holds different scenes, as a real one
/// does: the same step repeated would compress far better than real traffic).
const SCENES: u64 = 16;

pub fn bench_hosts(args: &HostsBenchArgs) -> Result<()> {
    let config = rundir::config::RunConfig::load(&args.config)?;
    let steps = (0..SCENES)
        .map(|seed| real_step(&config.sim, seed))
        .collect::<Result<Vec<_>>>()?;
    let step_bytes = steps.iter().map(Vec::len).sum::<usize>() / steps.len();
    let packing = packing(&steps)?;
    let weights = qnet::QNets::new(&config.net, &qnet::Device::flex()).to_bytes()?;
    let dir = tempfile::tempdir()?;
    let secret = RunSecret::create_or_keep(&dir.path().join("run.secret"), RUN_ID)?;
    let endpoint: Endpoint = format!("tcp/127.0.0.1:{}", free_port()?).parse()?;
    let central = session::listen(&endpoint, &secret)?;
    let hosts = (0..FANOUT_HOSTS)
        .map(|_| session::connect(&endpoint, RUN_ID, &secret))
        .collect::<Result<Vec<_>>>()?;

    let reps = args.reps.max(1);
    let parcels = args.steps.div_ceil(packing.steps_per_parcel);
    let mut figures = [Vec::new(), Vec::new(), Vec::new(), Vec::new()];
    for _ in 0..reps {
        let per_parcel = packing.steps_per_parcel as f64;
        figures[0].push(zenoh_steps(&central, &hosts[0], &packing.parcel, parcels)? * per_parcel);
        figures[1].push(tcp_steps(&packing.parcel, parcels)? * per_parcel);
        figures[2].push(zenoh_steps(&central, &hosts[0], &steps[0], args.steps)?);
        figures[3].push(tcp_steps(&steps[0], args.steps)?);
    }
    let [zenoh, tcp, zenoh_raw, tcp_raw] = figures.map(median);
    let fanout = weights_fanout(&central, &hosts, &weights, args.publications.max(1))?;
    let wire_bytes_per_step = packing.parcel.len() as f64 / packing.steps_per_parcel as f64;
    let figures = HostsFigures {
        side: config.sim.grid()?.side(),
        step_bytes,
        steps: args.steps,
        steps_per_parcel: packing.steps_per_parcel,
        parcel_bytes: packing.parcel.len(),
        compression_ratio: step_bytes as f64 / wire_bytes_per_step,
        pack_us_per_step: packing.pack_us_per_step,
        unpack_us_per_step: packing.unpack_us_per_step,
        zenoh_steps_per_s: zenoh,
        tcp_steps_per_s: tcp,
        zenoh_over_tcp: zenoh / tcp,
        zenoh_mb_per_s: zenoh * wire_bytes_per_step / 1e6,
        tcp_mb_per_s: tcp * wire_bytes_per_step / 1e6,
        zenoh_raw_steps_per_s: zenoh_raw,
        tcp_raw_steps_per_s: tcp_raw,
        zenoh_raw_over_tcp: zenoh_raw / tcp_raw,
        bridge_steps_per_s: [
            zenoh,
            1e6 / packing.pack_us_per_step,
            1e6 / packing.unpack_us_per_step,
        ]
        .into_iter()
        .fold(f64::INFINITY, f64::min),
        weights_bytes: weights.len(),
        hosts: FANOUT_HOSTS,
        weights_fanout_ms: median(fanout.clone()),
        weights_fanout_max_ms: fanout.iter().copied().fold(0.0, f64::max),
    };
    print_figures(&serde_json::to_value(&figures)?, args.json)
}

/// A parcel as the bridge packs it from `steps` (as many as fit), and its cost.
struct Packing {
    parcel: Vec<u8>,
    steps_per_parcel: usize,
    pack_us_per_step: f64,
    unpack_us_per_step: f64,
}

fn packing(steps: &[Vec<u8>]) -> Result<Packing> {
    const TIMINGS: usize = 10;
    let mut packer = Packer::default();
    let mut parcel = Vec::new();
    let mut steps_per_parcel = 0;
    let start = Instant::now();
    for _ in 0..TIMINGS {
        for step in steps.iter().cycle() {
            packer.push(step);
            if packer.full() {
                break;
            }
        }
        steps_per_parcel = packer.len();
        parcel = packer.seal(1);
    }
    let pack = start.elapsed().as_secs_f64() / TIMINGS as f64;
    let start = Instant::now();
    for _ in 0..TIMINGS {
        let (_, Parcel::Messages(messages)) = parcel::unpack(&parcel)? else {
            anyhow::bail!("a parcel of steps came back as another kind");
        };
        ensure!(messages.len() == steps_per_parcel, "a parcel lost steps");
    }
    let unpack = start.elapsed().as_secs_f64() / TIMINGS as f64;
    let per_step = 1e6 / steps_per_parcel as f64;
    Ok(Packing {
        parcel,
        steps_per_parcel,
        pack_us_per_step: pack * per_step,
        unpack_us_per_step: unpack * per_step,
    })
}

/// A step as an actor ships it: a settled scene of ten blocks at the run's resolution.
fn real_step(config: &SimConfig, seed: u64) -> Result<Vec<u8>> {
    let obs = rendered_scene(config, 10, seed)?;
    let goal = obs.visible_ids()[0];
    let step = Step {
        origin: Origin {
            actor: 0,
            incarnation: 0,
            seq: 0,
        },
        transition: experience::Transition {
            episode: 0,
            step: 0,
            goal,
            obs,
            action: sim::Action {
                primitive: sim::Primitive::Grasp,
                rotation: 3,
                row: 50,
                col: 60,
            },
            reward: 1.0,
            grasped: Some(goal),
            next_value: None,
            next: None,
        },
        priority: 1.0,
        predicted_q: 0.5,
        explored: false,
        weights_version: 0,
    };
    let mut bytes = Vec::new();
    wire::encode_into(&Message::Step(step), &mut bytes);
    Ok(bytes)
}

fn free_port() -> Result<u16> {
    Ok(TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// What a receiver computes from every byte of a message.
fn checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |sum, b| sum ^ b)
}

/// Steps/s from a joined host's session to the central one, as the bridge publishes them.
fn zenoh_steps(
    central: &bridge::zenoh::Session,
    host: &bridge::zenoh::Session,
    step: &[u8],
    steps: usize,
) -> Result<f64> {
    let keys = Keys::new(RUN_ID);
    let subscriber = link::subscriber(central, keys.every_host(Stream::Steps))?;
    let publisher = link::publisher(host, Stream::Steps, keys.stream(Stream::Steps, "host-0"))?;
    wait_for_match(&publisher)?;
    let expected = checksum(step);
    let start = Instant::now();
    let elapsed = std::thread::scope(|scope| {
        let receiver = scope.spawn(|| -> Result<Duration> {
            for _ in 0..steps {
                let sample = subscriber
                    .recv()
                    .map_err(|e| anyhow::anyhow!("receiving: {e}"))?;
                ensure!(
                    checksum(&sample.payload().to_bytes()) == expected,
                    "a step changed"
                );
            }
            Ok(start.elapsed())
        });
        for _ in 0..steps {
            publisher
                .put(step.to_vec())
                .wait()
                .map_err(|e| anyhow::anyhow!("publishing: {e}"))?;
        }
        receiver.join().expect("the receiver does not panic")
    })?;
    Ok(steps as f64 / elapsed.as_secs_f64())
}

/// Waits until a publisher's subscriber is known to its session.
fn wait_for_match(publisher: &bridge::zenoh::pubsub::Publisher<'_>) -> Result<()> {
    let deadline = Instant::now() + Duration::from_secs(10);
    while !publisher
        .matching_status()
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))?
        .matching()
    {
        ensure!(Instant::now() < deadline, "the subscriber never matched");
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(())
}

/// Steps/s over a plain TCP socket on loopback, each length-prefixed.
fn tcp_steps(step: &[u8], steps: usize) -> Result<f64> {
    let listener = TcpListener::bind("127.0.0.1:0")?;
    let address = listener.local_addr()?;
    let expected = checksum(step);
    std::thread::scope(|scope| {
        let receiver = scope.spawn(|| -> Result<Instant> {
            let (mut socket, _) = listener.accept()?;
            let mut message = Vec::new();
            for _ in 0..steps {
                let mut len = [0u8; 4];
                socket.read_exact(&mut len)?;
                message.resize(u32::from_le_bytes(len) as usize, 0);
                socket.read_exact(&mut message)?;
                ensure!(checksum(&message) == expected, "a step changed");
            }
            Ok(Instant::now())
        });
        let mut socket = TcpStream::connect(address).context("connecting over loopback")?;
        let start = Instant::now();
        let len = (step.len() as u32).to_le_bytes();
        for _ in 0..steps {
            socket.write_all(&len)?;
            socket.write_all(step)?;
        }
        let end = receiver.join().expect("the receiver does not panic")?;
        Ok(steps as f64 / (end - start).as_secs_f64())
    })
}

/// Milliseconds from each publication of the weights to the last host receiving it.
fn weights_fanout(
    central: &bridge::zenoh::Session,
    hosts: &[bridge::zenoh::Session],
    weights: &[u8],
    publications: usize,
) -> Result<Vec<f64>> {
    let keys = Keys::new(RUN_ID);
    let key = keys.stream(Stream::Weights, "");
    let publisher = link::publisher(central, Stream::Weights, key.clone())?;
    let subscribers = hosts
        .iter()
        .map(|host| link::subscriber(host, key.clone()))
        .collect::<Result<Vec<_>>>()?;
    wait_for_match(&publisher)?;
    // Every host's subscription reaches the central session before the first timing.
    std::thread::sleep(Duration::from_millis(200));
    let mut fanout = Vec::new();
    for _ in 0..publications {
        let start = Instant::now();
        publisher
            .put(weights.to_vec())
            .wait()
            .map_err(|e| anyhow::anyhow!("publishing: {e}"))?;
        let mut last = start;
        for subscriber in &subscribers {
            let sample = subscriber
                .recv_timeout(Duration::from_secs(10))
                .map_err(|e| anyhow::anyhow!("{e}"))?
                .context("a host never received the weights")?;
            ensure!(
                sample.payload().len() == weights.len(),
                "the weights changed"
            );
            last = last.max(Instant::now());
        }
        fanout.push((last - start).as_secs_f64() * 1e3);
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(fanout)
}
