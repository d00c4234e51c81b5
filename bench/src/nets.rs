//! `pushgrasp bench learner`: the Q-networks' inference on all rotations and their training
//! steps, FLOP rates beside the backend's matmul peak, and onnxruntime's inference and
//! PyTorch's training step of the same nets beside them.

mod peers;
mod side;

use anyhow::Result;
use clap::Args;
use learner::{LearningConfig, TrainedNet, Trainer};
use qnet::{ActingNets, Device, Difference, Inference, NetInput, QNetConfig, QNets, RotatedQMaps};
use rundir::backend::Backend;
use serde_json::{Map, Value};
use sim::{Camera, Primitive, ROTATIONS, SimConfig, Tabletop};

use super::thread_cpu::ThreadCpu;
use super::{median, ms, print_figures, python, timed};
use peers::Peers;
use side::{
    SideFigures, SideNets, Training, both_ms, publish_ms, rotated_planes, samples, train_step_ms,
};

#[derive(Args)]
pub struct LearnerBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Repetitions of each timed figure (medians are reported).
    #[arg(long, default_value_t = 10)]
    reps: usize,
    /// Time the nets of this run config's `[net]` (default: the library's default shape).
    #[arg(long)]
    config: Option<std::path::PathBuf>,
    /// The Python that runs the peers beside ours (onnxruntime and numpy; PyTorch where
    /// installed) [default: target/bench-venv/bin/python3 when it exists, else python3].
    #[arg(long)]
    python: Option<std::path::PathBuf>,
    /// Leave the peers out.
    #[arg(long)]
    no_peer: bool,
    /// The backend timed, `cpu` or `wgpu` (a wgpu build); on wgpu, the same nets on the CPU
    /// give `max_rel_diff_vs_cpu` and the CPU's training step beside it.
    #[arg(long, default_value_t = Backend::Cpu)]
    backend: Backend,
    /// Heightmap sides timed (pixels; the workspace is divided into side x side).
    #[arg(long, value_delimiter = ',', default_values_t = [112, 224])]
    sides: Vec<u32>,
    /// With the kernel counts of a GPU backend, each call's kernels by name
    /// (`<call>_kernel_names_<side>`, most launched first).
    #[arg(long)]
    kernel_names: bool,
    /// Side of the square matrices whose product gives `matmul_peak_gflops` (a software
    /// device takes tens of seconds at the default).
    #[arg(long, default_value_t = 1024)]
    peak_side: usize,
}

pub fn bench_learner(args: &LearnerBenchArgs) -> Result<()> {
    let open = rundir::backend::open(args.backend, "learner")?;
    let run = Run {
        args,
        reps: args.reps.max(1),
        net: match &args.config {
            Some(path) => rundir::config::RunConfig::load(path)?.net,
            None => QNetConfig::default(),
        },
        device: open.device,
    };
    let mut figures = shape_figures(args.backend, open.adapter.as_ref(), &run.net)?;
    let python = args.python.clone().unwrap_or_else(python::default_python);
    let mut peers = Peers::new(python, run.reps);
    for &side in &args.sides {
        run.side_figures(side, &mut figures, &mut peers)?;
    }
    figures.insert(
        "matmul_peak_gflops".into(),
        matmul_peak_gflops(&run.device, args.peak_side, run.reps).into(),
    );
    peers.report(args.no_peer, &mut figures);
    print_figures(&Value::Object(figures), args.json)
}

/// What the bench times with: the nets' shape and their device.
struct Run<'a> {
    args: &'a LearnerBenchArgs,
    reps: usize,
    net: QNetConfig,
    device: Device,
}

/// The backend, its adapter and the nets' shape.
fn shape_figures(
    backend: Backend,
    adapter: Option<&qnet::Adapter>,
    net: &QNetConfig,
) -> Result<Map<String, Value>> {
    let mut figures = Map::new();
    figures.insert("backend".into(), backend.name().into());
    if let Some(adapter) = adapter {
        figures.insert("adapter".into(), adapter.name.clone().into());
        figures.insert("adapter_driver".into(), adapter.driver.clone().into());
        figures.insert("adapter_api".into(), adapter.api.clone().into());
    }
    figures.insert(
        "trunk_widths".into(),
        serde_json::to_value(&net.trunk_widths)?,
    );
    figures.insert(
        "context_dilations".into(),
        serde_json::to_value(&net.context_dilations)?,
    );
    figures.insert("fuse_context".into(), net.fuse_context.into());
    figures.insert(
        "rotation_equivariant".into(),
        net.rotation_equivariant.into(),
    );
    Ok(figures)
}

impl Run<'_> {
    /// Times the nets at heightmap side `side`: inference, training steps, publication, and
    /// the peers and the CPU beside them.
    fn side_figures(
        &self,
        side: u32,
        figures: &mut Map<String, Value>,
        peers: &mut Peers,
    ) -> Result<()> {
        let (s, mut trainer) = self.side_nets(side)?;
        let mut put = SideFigures {
            figures,
            suffix: format!("_{}", s.side),
        };
        let infer = self.inference(&s, &mut put);
        let [colour, depth, mask] = rotated_planes(&s);
        let rotated = [colour.as_slice(), &depth, &mask];
        if let ActingNets::Cpu(inference) = &s.acting {
            self.onnxruntime(&s, inference, rotated, infer, &mut put, peers);
        }
        let training = self.training(&s, &mut trainer)?;
        if self.args.backend != Backend::Cpu {
            self.versus_cpu(&s, &training, &mut put)?;
        }
        let gflop_batch_train = self.flop_figures(&s, infer, &training, &mut put);
        if !self.args.no_peer {
            // Beside a GPU backend, PyTorch steps on CUDA: the GPU step ours is measured against.
            let device = match self.args.backend {
                Backend::Cpu => "cpu",
                Backend::Wgpu => "cuda",
            };
            peers.torch(&s, rotated, &training, gflop_batch_train, device, &mut put);
        }
        self.kernel_figures(&s, &mut trainer, &mut put)
    }

    /// The kernels that one more of each timed call launches, on a GPU backend (the host's
    /// share of a GPU step grows with them); nothing on the CPU.
    fn kernel_figures(
        &self,
        s: &SideNets,
        trainer: &mut Trainer,
        put: &mut SideFigures,
    ) -> Result<()> {
        let mut count = |call_name: &str, call: &mut dyn FnMut() -> Result<()>| {
            let (done, launches) = qnet::kernels::count(&self.device, call);
            if let Some(launches) = launches {
                put.put(&format!("{call_name}_kernels"), launches.total() as f64);
                if self.args.kernel_names {
                    let names = launches
                        .by_name()
                        .iter()
                        .map(|(n, k)| (n.clone(), (*k).into()));
                    put.put_value(
                        &format!("{call_name}_kernel_names"),
                        Value::Object(names.collect()),
                    );
                }
            }
            done
        };
        let primitives = [Primitive::Push, Primitive::Grasp];
        count("infer_16rot", &mut || {
            s.acting
                .all_rotations_of_each(primitives, &[&s.input], &s.geometry)
                .map(drop)
                .map_err(Into::into)
        })?;
        let [one, eight] = [1, 8].map(|batch| samples(s, batch));
        count("train_step", &mut || {
            trainer.train_step(&one).map(drop).map_err(Into::into)
        })?;
        count("batch_train", &mut || {
            trainer.train_step(&eight).map(drop).map_err(Into::into)
        })?;
        count("publish", &mut || {
            trainer
                .published_nets()
                .to_bytes()
                .map(drop)
                .map_err(Into::into)
        })
    }

    /// The nets at side `side` and the trainer of the grasp net.
    fn side_nets(&self, side: u32) -> Result<(SideNets, Trainer)> {
        let config = SimConfig::with_pixel_size(sim::workspace::SIDE / side as f32);
        let (tabletop, _) = Tabletop::random(&config, 10, 0)?;
        let maps = Camera::new(tabletop.grid()).render(&tabletop);
        let side = maps.side();
        let goal = maps.visible_ids()[0];
        let input = NetInput::encode(&maps, goal);
        let trainer = Trainer::new(
            QNets::new(&self.net, &self.device),
            &self.net,
            side,
            &LearningConfig::default(),
            TrainedNet::Grasp,
            &self.device,
        );
        let nets = trainer.published_nets();
        let geometry = trainer.geometry().clone();
        let acting = ActingNets::new(&nets)?;
        let passes = ROTATIONS as usize / self.net.group();
        let s = SideNets {
            side,
            input,
            nets,
            geometry,
            acting,
            passes,
        };
        Ok((s, trainer))
    }

    /// What the actors run (both nets on each rotated input), and burn's own forward of the
    /// same nets beside it (on a GPU the actors run burn's forward: timed once). Gives the
    /// actors' time.
    fn inference(&self, s: &SideNets, put: &mut SideFigures) -> f64 {
        let infer = median(
            (0..self.reps)
                .map(|_| {
                    let primitives = [Primitive::Push, Primitive::Grasp];
                    let run = || {
                        s.acting
                            .all_rotations_of_each(primitives, &[&s.input], &s.geometry)
                    };
                    ms(timed(|| run().expect("inference")).1)
                })
                .collect(),
        );
        let burn_infer = match &s.acting {
            ActingNets::Cpu(_) => both_ms(self.reps, &|primitive| {
                s.nets
                    .all_rotations(primitive, &s.input, &s.geometry)
                    .expect("inference");
            }),
            ActingNets::Device(_) => infer,
        };
        put.put("infer_16rot_ms", infer);
        put.put("burn_infer_16rot_ms", burn_infer);
        infer
    }

    /// The convolutions alone (what onnxruntime runs) beside all of the inference, and
    /// onnxruntime's inference of the same nets unless the peers are left out.
    fn onnxruntime(
        &self,
        s: &SideNets,
        inference: &Inference,
        rotated: [&[f32]; 3],
        infer: f64,
        put: &mut SideFigures,
        peers: &mut Peers,
    ) {
        let convs = both_ms(self.reps, &|primitive| {
            inference.low_maps(primitive, rotated, &s.geometry);
        });
        put.put("infer_convs_ms", convs);
        put.put("infer_rotations_ms", infer - convs);
        if !self.args.no_peer {
            peers.onnxruntime(s, inference, rotated, infer, put);
        }
    }

    /// One-grasp and batch training steps, and publications of the trained nets.
    fn training(&self, s: &SideNets, trainer: &mut Trainer) -> Result<Training> {
        let (train, _) = train_step_ms(trainer, &samples(s, 1), self.reps)?;
        // The default learning config keeps no average: the published nets are the trained.
        let before_batch = trainer.published_nets();
        let threads_before = ThreadCpu::now();
        let (batch_train, first_batch) = train_step_ms(trainer, &samples(s, 8), self.reps)?;
        let threads = ThreadCpu::now().zip(threads_before);
        let publish = publish_ms(trainer, self.reps)?;
        Ok(Training {
            train,
            batch_train,
            publish,
            before_batch,
            first_batch,
            threads,
        })
    }

    /// The same weights on the CPU: how far this device's Q maps are from the CPU's, and the
    /// CPU's training step beside this device's.
    fn versus_cpu(&self, s: &SideNets, training: &Training, put: &mut SideFigures) -> Result<()> {
        let cpu = Device::flex();
        let cpu_nets = QNets::new(&self.net, &cpu).load_bytes(&s.nets.to_bytes()?)?;
        let cpu_acting = ActingNets::new(&cpu_nets)?;
        let mut worst = 0f32;
        for primitive in [Primitive::Push, Primitive::Grasp] {
            let here = s.acting.all_rotations(primitive, &s.input, &s.geometry)?;
            let there = cpu_acting.all_rotations(primitive, &s.input, &s.geometry)?;
            let difference = Difference::between(here.values(), there.values());
            worst = qnet::agreement::worst(worst, difference.max_rel);
        }
        put.put("max_rel_diff_vs_cpu", f64::from(worst));
        let learning = LearningConfig::default();
        let mut cpu_trainer = Trainer::new(
            cpu_nets,
            &self.net,
            s.side,
            &learning,
            TrainedNet::Grasp,
            &cpu,
        );
        let (cpu_batch_train, _) = train_step_ms(&mut cpu_trainer, &samples(s, 8), self.reps)?;
        put.put("cpu_batch_train_step_ms", cpu_batch_train);
        put.put("cpu_publish_ms", publish_ms(&cpu_trainer, self.reps)?);
        put.put(
            "batch_train_speedup_vs_cpu",
            cpu_batch_train / training.batch_train,
        );
        // Where the host's time went in those steps (the untimed one before them too).
        if let Some((after, before)) = training.threads {
            let used = after.since(before);
            let per_step_ms = |s: f64| s * 1e3 / (self.reps + 1) as f64;
            put.put("batch_train_fusion_cpu_ms", per_step_ms(used.fusion_s));
            put.put("batch_train_server_cpu_ms", per_step_ms(used.server_s));
            put.put("batch_train_other_cpu_ms", per_step_ms(used.other_s));
        }
        Ok(())
    }

    /// The times of the training steps and publication, and the FLOP rates of inference and
    /// of the batch step. Gives the batch step's GFLOP.
    fn flop_figures(
        &self,
        s: &SideNets,
        infer: f64,
        training: &Training,
        put: &mut SideFigures,
    ) -> f64 {
        let per_pass = self.net.flops_per_pass(s.geometry.padded());
        let gflop_inference = 2.0 * s.passes as f64 * per_pass / 1e9;
        // A grasp trains its rotation and the symmetric one, one pass or two (an equivariant
        // net's pass scores angles a quarter turn apart); backward costs about twice the
        // forward.
        let [first, symmetric] =
            [0, ROTATIONS / 2].map(|k| qnet::equivariant::pass_and_channel(k, self.net.group()).0);
        let passes_per_grasp = if first == symmetric { 1.0 } else { 2.0 };
        let gflop_batch_train = 3.0 * 8.0 * passes_per_grasp * per_pass / 1e9;
        put.put("train_step_ms", training.train);
        put.put("batch_train_step_ms", training.batch_train);
        put.put("publish_ms", training.publish);
        put.put("gflop_per_inference", gflop_inference);
        put.put(
            "achieved_gflops",
            gflop_batch_train / (training.batch_train / 1e3),
        );
        put.put("inference_gflops", gflop_inference / (infer / 1e3));
        gflop_batch_train
    }
}

/// The backend's rate on a large square matrix product, the ceiling for the nets.
fn matmul_peak_gflops(device: &burn::tensor::Device, n: usize, reps: usize) -> f64 {
    use burn::tensor::{Distribution, Tensor};
    let a = Tensor::<2>::random([n, n], Distribution::Default, device);
    let b = Tensor::<2>::random([n, n], Distribution::Default, device);
    // A value read back: a GPU backend only queues the product.
    let run = || a.clone().matmul(b.clone()).sum().into_scalar::<f32>();
    run();
    let best = (0..reps)
        .map(|_| timed(run).1.as_secs_f64())
        .fold(f64::MAX, f64::min);
    2.0 * (n * n * n) as f64 / best / 1e9
}
