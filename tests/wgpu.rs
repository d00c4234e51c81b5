//! The GPU path (burn-wgpu) against the CPU backend on this machine's adapter — Mesa's
//! software Vulkan (lavapipe) where there is no GPU, as in CI: the same Q maps from the
//! same weights, the same training step, checkpoints that move between the two, and a real
//! run with its learner on wgpu, and machines refused before a run starts. Built with
//! `--features wgpu` alone (`make test-gpu` runs it).
//! Speed is no target here: lavapipe multiplies at about 2 GFLOP/s.
#![cfg(feature = "wgpu")]

use std::sync::{Mutex, MutexGuard};

use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use learner::adam::Adam;
use learner::{Checkpoint, LearningConfig, Manifest, Sample, SavedNets, TrainedNet, Trainer};
use qnet::{ActingNets, Backend, Difference, NetInput, QNetConfig, QNets, RotatedQMaps};
use sim::{Action, Camera, Primitive, SimConfig, Tabletop};

mod common;
#[path = "common/stage1.rs"]
mod stage1;

use common::{pushgrasp_fails, pushgrasp_ok};

/// The Q maps of both nets must agree this closely (of their scale).
const AGREEMENT: f32 = 1e-3;

/// ... and after one training step on each backend, this closely: a weight whose gradient
/// is below the two backends' rounding takes Adam's first step (about the learning rate,
/// whatever the gradient's size) either way, and the rare few that went the other way move
/// the maps by a few thousandths of their scale between them.
const AGREEMENT_AFTER_A_STEP: f32 = 5e-3;

/// One test at a time on the device: lavapipe's threads take every core, and a run's
/// learner starved of them goes silent past its heartbeat.
static DEVICE: Mutex<()> = Mutex::new(());

fn device_turn() -> MutexGuard<'static, ()> {
    DEVICE
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn gpu() -> Device {
    let open = Backend::Wgpu
        .open()
        .expect("a wgpu adapter: `make test` installs Mesa's lavapipe");
    println!("adapter: {}", open.adapter.expect("wgpu names its adapter"));
    open.device
}

/// The stage configs' nets (context convolutions), the library's default shape, and the
/// stage nets rotation-equivariant (four passes, each scoring four angles).
fn net_shapes() -> [QNetConfig; 3] {
    let stage = QNetConfig {
        trunk_widths: vec![8, 16],
        context_dilations: vec![1, 2],
        head_width: 64,
        ..QNetConfig::default()
    };
    let equivariant = QNetConfig {
        rotation_equivariant: true,
        ..stage.clone()
    };
    [QNetConfig::default(), stage, equivariant]
}

fn scene_input(goal_index: usize) -> NetInput {
    let config = SimConfig::with_pixel_size(0.004);
    let (tabletop, _) = Tabletop::random(&config, 6, 5).unwrap();
    let maps = Camera::new(tabletop.grid()).render(&tabletop);
    let goal = maps.visible_ids()[goal_index];
    NetInput::encode(&maps, goal)
}

/// Grasps at several pixels and rotations of one scene, labelled 0 or 1.
fn samples(input: &NetInput, n: usize) -> Vec<Sample> {
    (0..n)
        .map(|k| Sample {
            input: input.clone(),
            action: Action {
                primitive: Primitive::Grasp,
                rotation: (3 * k % 16) as u8,
                row: input.side / 3 + 7 * k,
                col: input.side / 2 + 5 * k,
            },
            label: (k % 2) as f32,
            weight: 1.0,
            succeeded: k % 2 == 1,
        })
        .collect()
}

fn trainer(nets: QNets, net: &QNetConfig, side: usize, device: &Device) -> Trainer {
    let learning = LearningConfig::default();
    Trainer::new(nets, net, side, &learning, TrainedNet::Grasp, device)
}

/// Nets trained a few steps on the CPU: weights, batch-norm scales and running statistics
/// all moved from their initial values.
fn trained_on_cpu(net: &QNetConfig, input: &NetInput) -> QNets {
    let cpu = Device::flex();
    cpu.seed(7);
    let mut trainer = trainer(QNets::new(net, &cpu), net, input.side, &cpu);
    for _ in 0..3 {
        trainer.train_step(&samples(input, 4)).unwrap();
    }
    trainer.published_nets()
}

fn on(device: &Device, net: &QNetConfig, nets: &QNets) -> QNets {
    QNets::new(net, device)
        .load_bytes(&nets.to_bytes().unwrap())
        .unwrap()
}

/// Both nets' Q maps over all 16 rotations, `ours` against `reference`: of `input`, and of
/// it together with its mirror image in one batch (each input sent once and rotated on the
/// device) as an actor runs them (on a device, laid out in full, their convolution weights
/// channels-last).
fn maps_agree(
    ours: &QNets,
    reference: &QNets,
    net: &QNetConfig,
    input: &NetInput,
    (what, agreement): (&str, f32),
) {
    let geometry = qnet::Geometry::new(input.side, net);
    let mirror = input.mirrored();
    let primitives = [Primitive::Push, Primitive::Grasp];
    let batch = ActingNets::new(ours)
        .unwrap()
        .all_rotations_of_each(primitives, &[input, &mirror], &geometry)
        .unwrap();
    for (i, primitive) in primitives.into_iter().enumerate() {
        let alone = ours.all_rotations(primitive, input, &geometry).unwrap();
        for (got, (of, input)) in [&alone, &batch[0][i], &batch[1][i]].into_iter().zip([
            ("alone", input),
            ("batched", input),
            ("batched", &mirror),
        ]) {
            let want = reference
                .all_rotations(primitive, input, &geometry)
                .unwrap();
            let d = Difference::between(got.values(), want.values());
            println!(
                "{what}, {primitive:?}, context {:?}, {of}: max abs difference {:e}, relative {:e}",
                net.context_dilations, d.max_abs, d.max_rel
            );
            assert!(d.max_rel <= agreement, "{what}, {primitive:?}, {of}: {d:?}");
        }
    }
}

#[test]
fn both_nets_give_the_cpus_q_maps_over_16_rotations() {
    let _turn = device_turn();
    let gpu = gpu();
    let input = scene_input(0);
    for net in net_shapes() {
        let cpu_nets = trained_on_cpu(&net, &input);
        maps_agree(
            &on(&gpu, &net, &cpu_nets),
            &cpu_nets,
            &net,
            &input,
            ("wgpu vs cpu", AGREEMENT),
        );
    }
}

/// The kernels one net's Q maps launch on the device, for 1 rotation and for all 16, and
/// those of a training step on 1 sample and on 8 at 8 rotations: the rotations and the
/// samples are one batch, so more of them must not mean more kernels (a pass per rotation
/// would launch 16 times as many).
#[test]
fn the_rotations_and_a_batchs_samples_launch_the_kernels_of_one() {
    let _turn = device_turn();
    let gpu = gpu();
    let input = scene_input(0);
    for net in net_shapes() {
        let geometry = qnet::Geometry::new(input.side, &net);
        let nets = on(&gpu, &net, &trained_on_cpu(&net, &input));
        let acting = ActingNets::new(&nets).unwrap();
        let kernels = |rotations: &[u8]| {
            let call = || acting.rotations(Primitive::Grasp, &input, rotations, &geometry);
            let (maps, launches) = qnet::kernels::count(&gpu, call);
            maps.unwrap();
            launches.expect("a wgpu device counts its launches").total()
        };
        // The first call compiles and lays out what the later ones reuse.
        kernels(&[0]);
        let all: Vec<u8> = (0..16).collect();
        let (one, sixteen) = (kernels(&[0]), kernels(&all));
        let mut trainer = trainer(nets, &net, input.side, &gpu);
        let mut step = |n: usize| {
            let batch = samples(&input, n);
            let (report, launches) = qnet::kernels::count(&gpu, || trainer.train_step(&batch));
            report.unwrap();
            launches.unwrap()
        };
        step(8);
        let (single, eight) = (step(1), step(8));
        // CubeCL's copy to a contiguous layout: what a convolution launched for a weight
        // laid out as burn lays it out, before itself and before its input's gradient.
        let copies: u64 = eight
            .by_name()
            .iter()
            .filter(|(name, _)| name == "CopyKernel")
            .map(|(_, n)| n)
            .sum();
        let (single, eight) = (single.total(), eight.total());
        println!(
            "context {:?}, equivariant {}: Q maps {one} kernels for 1 rotation, {sixteen} \
             for 16; a training step {single} for 1 sample, {eight} for 8, {copies} of \
             them copies",
            net.context_dilations, net.rotation_equivariant
        );
        // The weights are held channels-last and Adam keeps them so: the one copy left
        // is the loss's gradient's.
        if !net.rotation_equivariant {
            assert!(copies <= 1, "a step made {copies} copies");
        }
        assert!(one > 0 && single > 0);
        assert!(
            sixteen < 2 * one,
            "{sixteen} kernels for 16 rotations, {one} for 1"
        );
        assert!(
            eight < 2 * single,
            "{eight} kernels for 8 samples, {single} for 1"
        );
    }
}

/// Every float tensor of a module (weights, biases, batch-norm scales, shifts and running
/// statistics), in visiting order.
#[derive(Default)]
struct Floats(Vec<Vec<f32>>);

impl ModuleVisitor for Floats {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.0
            .push(param.val().into_data().try_to_vec::<f32>().unwrap());
    }
}

fn floats(nets: &QNets) -> Vec<Vec<f32>> {
    let mut floats = Floats::default();
    nets.visit(&mut floats);
    floats.0
}

#[test]
fn one_training_step_gives_the_cpus_loss_and_weights() {
    let _turn = device_turn();
    let gpu = gpu();
    let input = scene_input(1);
    // The stage nets, and the same rotation-equivariant, whose weights are gathered from
    // their base kernels (the gradient summing each one's copies).
    let [_, stage, equivariant] = net_shapes();
    for net in [stage, equivariant] {
        let start = trained_on_cpu(&net, &input);
        let batch = samples(&input, 4);
        let mut on_cpu = trainer(start.clone(), &net, input.side, &Device::flex());
        let mut on_gpu = trainer(on(&gpu, &net, &start), &net, input.side, &gpu);
        let cpu_step = on_cpu.train_step(&batch).unwrap();
        let gpu_step = on_gpu.train_step(&batch).unwrap();
        let loss = Difference::between(&[gpu_step.loss], &[cpu_step.loss]);
        println!(
            "loss: cpu {}, wgpu {}, relative difference {:e}",
            cpu_step.loss, gpu_step.loss, loss.max_rel
        );
        assert!(loss.max_rel <= AGREEMENT, "loss: {loss:?}");
        let q = Difference::between(&gpu_step.predicted, &cpu_step.predicted);
        assert!(q.max_rel <= AGREEMENT, "predicted Q: {q:?}");
        // The weights after the step. Adam's first step moves a weight by about the learning
        // rate whatever its gradient's size, so a gradient below the two backends' rounding
        // steps either way: each weight must be within two steps (and 1e-3 of its tensor's
        // scale) of the CPU's, and those stepping the other way must be a rare few.
        let lr = LearningConfig::default().learning_rate as f32;
        let (before, cpu_after, gpu_after) = (
            floats(&start),
            floats(&on_cpu.published_nets()),
            floats(&on_gpu.published_nets()),
        );
        assert_eq!(cpu_after.len(), gpu_after.len());
        let (mut moved, mut reversed, mut total) = (0, 0, 0);
        for ((was, cpu), gpu) in before.iter().zip(&cpu_after).zip(&gpu_after) {
            let scale = cpu.iter().fold(0f32, |m, w| m.max(w.abs()));
            for ((w, c), g) in was.iter().zip(cpu).zip(gpu) {
                assert!(
                    (c - g).abs() <= 2.0 * lr + AGREEMENT * scale,
                    "a weight went from {w} to {c} on the cpu, to {g} on wgpu"
                );
                total += 1;
                moved += usize::from(c != w);
                reversed += usize::from((c - w) * (g - w) < 0.0);
            }
        }
        println!("weights: {moved} of {total} moved; {reversed} the other way on wgpu");
        assert!(moved > 0, "the step moved no weight");
        assert!(
            reversed * 100 < moved,
            "{reversed} of {moved} weights stepped the other way"
        );
        maps_agree(
            &on_gpu.published_nets(),
            &on_cpu.published_nets(),
            &net,
            &input,
            ("after one step, wgpu vs cpu", AGREEMENT_AFTER_A_STEP),
        );
    }
}

/// Values between -1 and 1 that differ from one to the next, the same on every device.
fn wavy<const D: usize>(shape: [usize; D], phase: f32, device: &Device) -> Tensor<D> {
    let n = shape.iter().product();
    let values: Vec<f32> = (0..n).map(|k| (k as f32 * 0.7 + phase).sin()).collect();
    Tensor::from_data(burn::tensor::TensorData::new(values, shape), device)
}

/// Three linear layers (six parameter tensors) trained four steps on `device` by `step`;
/// their weights after.
fn adam_trained(
    device: &Device,
    mut step: impl FnMut(Vec<burn::nn::Linear>, burn::optim::GradientsParams) -> Vec<burn::nn::Linear>,
) -> Vec<f32> {
    use burn::nn::{Linear, LinearConfig};
    use burn::optim::GradientsParams;
    let device = device.clone().autodiff();
    let mut layers: Vec<Linear> = (0..3)
        .map(|k| {
            let mut layer: Linear = LinearConfig::new(37, 37).init(&device);
            layer.weight = Param::from_tensor(wavy([37, 37], k as f32, &device));
            layer.bias = Some(Param::from_tensor(wavy([37], 1.0 + k as f32, &device)));
            layer
        })
        .collect();
    for step_index in 0..4 {
        let x = wavy([8, 37], step_index as f32, &device).mul_scalar(step_index as f32 + 1.0);
        let y = layers.iter().fold(x, |x, layer| layer.forward(x).tanh());
        let loss = y.powf_scalar(2.0).sum();
        let grads = GradientsParams::from_grads(loss.backward(), &layers);
        layers = step(layers, grads);
    }
    let mut floats = Floats::default();
    layers.visit(&mut floats);
    floats.0.concat()
}

/// Adam on the GPU (learner::adam: four tensors' steps a kernel, a kernel for each tensor
/// left over) must step as burn's own Adam: six tensors four steps, in three kernels a step
/// (four tensors, then each of two); and each kernel must give the CPU's values, writing a
/// parameter laid out as it lies (the trainer holds convolution weights channels-last) from
/// inputs laid out otherwise.
#[test]
fn adams_kernels_step_as_burns_adam_and_give_the_cpus_values() {
    use burn::backend::Dispatch;
    use burn::optim::AdamConfig;
    use burn::optim::decay::WeightDecayConfig;
    use learner::adam::{AdamBackend, StepFactors};
    let _turn = device_turn();
    let gpu = gpu();
    let mut ours = Adam::new(0.9, 0.99, 0.05);
    let mut kernels = Vec::new();
    let got = adam_trained(&gpu, |layers, grads| {
        let (layers, launches) = qnet::kernels::count(&gpu, || ours.step(1e-2, layers, grads));
        kernels.push(launches.expect("a wgpu device counts its launches"));
        layers
    });
    let mut burns = AdamConfig::new()
        .with_beta_1(0.9)
        .with_beta_2(0.99)
        .with_weight_decay(Some(WeightDecayConfig::new(0.05)))
        .init();
    // burn's Adam on the same device: the layers' passes are the same on both sides, so
    // what differs is Adam's (the passes' own differences from the CPU's, which Adam's
    // normalised step magnifies where a gradient is near zero, are not Adam's).
    let want = adam_trained(&gpu, |layers, grads| burns.step(1e-2, layers, grads));
    let d = Difference::between(&got, &want);
    println!("Adam, four steps, the wgpu kernels vs burn's Adam on wgpu: {d:?}");
    assert!(d.max_rel <= 1e-5, "{d:?}");
    // (The count holds what the backward pass left unrun too: fused element-wise kernels.)
    for launches in &kernels {
        println!("Adam's step: {:?}", launches.by_name());
        let mut adams: Vec<(&str, u64)> = (launches.by_name().iter())
            .filter(|(name, _)| name.starts_with("Adam"))
            .map(|(name, count)| (name.as_str(), *count))
            .collect();
        adams.sort();
        // One kernel for four tensors, one for each of the other two.
        let want = [("Adam4Kernel", 1), ("AdamKernel", 2)];
        assert_eq!(adams, want, "{:?}", launches.by_name());
    }

    // Parameters, gradients and moments laid out transposed in memory, which the kernels
    // write laid out as the parameters; then a step of those with the rest laid out
    // plainly: four tensors of different shapes in one kernel, and one alone.
    let factors = StepFactors {
        weight_decay: 0.05,
        beta_1: 0.9,
        beta_2: 0.99,
        combined: 0.8,
        epsilon: 1e-5,
        lr: 1e-2,
    };
    let steps = |device: &Device| {
        let shapes = [[37, 19], [5, 3], [64, 70], [1, 9], [19, 37]];
        let operands = |(k, &[a, b]): (usize, &[usize; 2]), transposed: bool| {
            let phase = k as f32;
            let tensor = |phase| match transposed {
                true => wavy([b, a], phase, device).transpose(),
                false => wavy([a, b], phase, device),
            };
            [
                tensor(phase),
                tensor(phase + 2.0),
                tensor(phase + 3.0).abs(),
                tensor(phase + 4.0).abs(),
            ]
            .map(|t| t.into_dispatch())
        };
        let step = |transposed: bool, params: Option<Vec<_>>| -> Vec<[_; 3]> {
            let mut all: Vec<[_; 4]> = shapes
                .iter()
                .enumerate()
                .map(|s| operands(s, transposed))
                .collect();
            if let Some(params) = params {
                for (operands, param) in all.iter_mut().zip(params) {
                    operands[0] = param;
                }
            }
            let last = all.pop().unwrap();
            let mut four = all.into_iter();
            let mut next = || four.next().unwrap();
            let ([p0, g0, m0, v0], [p1, g1, m1, v1], [p2, g2, m2, v2], [p3, g3, m3, v3]) =
                (next(), next(), next(), next());
            let (a, b, c, d) = Dispatch::adam_step_4(
                p0, g0, m0, v0, p1, g1, m1, v1, p2, g2, m2, v2, p3, g3, m3, v3, factors,
            );
            let [p, g, m, v] = last;
            let e = Dispatch::adam_step(p, g, m, v, factors);
            [a, b, c, d, e]
                .into_iter()
                .map(|(p, m, v)| [p, m, v])
                .collect()
        };
        let first = step(true, None);
        let params = first.into_iter().map(|[p, ..]| p).collect();
        let values = |t| {
            Tensor::<2>::from_dispatch(t)
                .into_data()
                .try_to_vec::<f32>()
                .unwrap()
        };
        step(false, Some(params))
            .into_iter()
            .flat_map(|outputs| outputs.map(values))
            .flatten()
            .collect::<Vec<f32>>()
    };
    let d = Difference::between(&steps(&gpu), &steps(&Device::flex()));
    println!("Adam, transposed parameters and gradients, wgpu vs cpu: {d:?}");
    assert!(d.max_rel <= 1e-5, "{d:?}");
}

/// A convolution's weight gradient on the host, from `[n, h, w, c]` values: `[o, k, k, c]`.
struct WeightGradCase {
    batch: usize,
    height: usize,
    width: usize,
    channels: usize,
    out_channels: usize,
    stride: usize,
    padding: usize,
    dilation: usize,
}

impl WeightGradCase {
    const KERNEL: usize = 3;

    fn out_side(&self, side: usize) -> usize {
        (side + 2 * self.padding - self.dilation * (Self::KERNEL - 1) - 1) / self.stride + 1
    }

    fn on_host(&self, input: &[f32], grad: &[f32]) -> Vec<f32> {
        let (k, c, o) = (Self::KERNEL, self.channels, self.out_channels);
        let (oh, ow) = (self.out_side(self.height), self.out_side(self.width));
        let mut weight_grad = vec![0.0; o * k * k * c];
        for n in 0..self.batch {
            for (oy, ox) in (0..oh).flat_map(|y| (0..ow).map(move |x| (y, x))) {
                for (ky, kx) in (0..k).flat_map(|y| (0..k).map(move |x| (y, x))) {
                    let y = (oy * self.stride + ky * self.dilation).checked_sub(self.padding);
                    let x = (ox * self.stride + kx * self.dilation).checked_sub(self.padding);
                    let (Some(y), Some(x)) = (y, x) else { continue };
                    if y >= self.height || x >= self.width {
                        continue;
                    }
                    for (co, ci) in (0..o).flat_map(|a| (0..c).map(move |b| (a, b))) {
                        let g = grad[((n * oh + oy) * ow + ox) * o + co];
                        let v = input[((n * self.height + y) * self.width + x) * c + ci];
                        weight_grad[((co * k + ky) * k + kx) * c + ci] += g * v;
                    }
                }
            }
        }
        weight_grad
    }
}

/// burn-cubecl's im2col weight gradient builds its columns in one kernel (vendor/README.md):
/// a tuner on a GPU takes it for the nets' 3x3 convolutions, where lavapipe's runs the
/// direct one, so it is called here directly, on the input laid out as the convolution
/// hands it over (channels last through strides). Its gradient must be the host's, for a
/// padded strided 3x3 over a plane that is not square and for a dilated one, in fewer
/// kernels than taps (the unpatched one launched two a tap and a fill: 19).
#[test]
fn the_im2col_weight_gradient_is_the_hosts_in_fewer_kernels_than_taps() {
    use burn::backend::DispatchDevice;
    use burn::backend::ops::FloatTensorOps;
    use burn::backend::wgpu::CubeBackend;
    use burn::tensor::ops::ConvOptions;
    use burn::tensor::{Shape, TensorData};
    use burn_cubecl::cubecl::future::block_on;

    let _turn = device_turn();
    let gpu = gpu();
    let DispatchDevice::Cube(device) = gpu.as_dispatch().clone() else {
        panic!("the wgpu device is a CubeCL one");
    };
    let base = WeightGradCase {
        batch: 2,
        height: 12,
        width: 9,
        channels: 3,
        out_channels: 4,
        stride: 2,
        padding: 1,
        dilation: 1,
    };
    let dilated = WeightGradCase {
        stride: 1,
        padding: 2,
        dilation: 2,
        ..base
    };
    for case in [base, dilated] {
        let (n, c, o, k) = (
            case.batch,
            case.channels,
            case.out_channels,
            WeightGradCase::KERNEL,
        );
        let (oh, ow) = (case.out_side(case.height), case.out_side(case.width));
        let wave = |len: usize, phase: f32| -> Vec<f32> {
            (0..len).map(|i| (i as f32 * 0.37 + phase).sin()).collect()
        };
        let input = wave(n * case.height * case.width * c, 0.0);
        let grad = wave(n * oh * ow * o, 1.0);
        // Channels first in memory, read channels last through strides.
        let nchw: Vec<f32> = (0..n * c * case.height * case.width)
            .map(|i| {
                let (x, rest) = (i % case.width, i / case.width);
                let (y, rest) = (rest % case.height, rest / case.height);
                let (ci, b) = (rest % c, rest / c);
                input[((b * case.height + y) * case.width + x) * c + ci]
            })
            .collect();
        let nchw = TensorData::new(nchw, [n, c, case.height, case.width]);
        let input_t =
            CubeBackend::float_permute(CubeBackend::float_from_data(nchw, &device), &[0, 2, 3, 1]);
        let grad_t =
            CubeBackend::float_from_data(TensorData::new(grad.clone(), [n, oh, ow, o]), &device);
        let options = ConvOptions::new([case.stride; 2], [case.padding; 2], [case.dilation; 2], 1);
        let (weight_grad, launches) = qnet::kernels::count(&gpu, || {
            burn_cubecl::kernel::conv::wgrad_im2col::<2>(
                input_t,
                grad_t,
                Shape::new([o, k, k, c]),
                options,
            )
            .expect("a dense 3x3 is one the im2col candidate takes")
        });
        let got = block_on(CubeBackend::float_into_data(weight_grad))
            .unwrap()
            .try_to_vec::<f32>()
            .unwrap();
        let d = Difference::between(&got, &case.on_host(&input, &grad));
        let launches = launches.expect("a wgpu device counts its launches");
        println!(
            "im2col weight gradient, stride {} dilation {}: {d:?}, kernels {:?}",
            case.stride,
            case.dilation,
            launches.by_name()
        );
        assert!(d.max_rel <= 1e-5, "{d:?}");
        assert!(
            launches.total() < (k * k) as u64,
            "{} kernels: {:?}",
            launches.total(),
            launches.by_name()
        );
    }
}

/// The batch norm's statistics (the running ones' update with them) and its gradients
/// (qnet::batch_norm) on the GPU are a kernel each, a cube a channel, and must give the
/// CPU's loops' values: for an input laid
/// out contiguously and for one laid out channels last, as a convolution hands it over, with
/// fewer values a channel than a cube's threads and with several times as many, and with
/// more channels than a cube takes side by side.
#[test]
fn the_batch_norms_statistics_and_gradients_are_the_cpus_in_a_kernel_each() {
    use burn::backend::Dispatch;
    use burn::tensor::TensorData;
    use qnet::batch_norm::NormBackend;

    let _turn = device_turn();
    let gpu = gpu();
    let epsilon = 1e-5;
    for ([n, c, h, w], channels_last) in [
        ([3, 5, 7, 6], false),
        ([2, 4, 30, 25], true),
        ([2, 3, 5, 70], true),
        ([2, 40, 3, 5], true),
    ] {
        let wave = |len: usize, rate: f32, scale: f32| -> Vec<f32> {
            (0..len)
                .map(|i| (i as f32 * rate).sin() * scale + 0.3)
                .collect()
        };
        let len = n * c * h * w;
        let (x, gamma) = (wave(len, 0.37, 2.0), wave(c, 0.9, 1.0));
        // The running mean and variance before the statistics' update.
        let running = [wave(c, 0.7, 0.2), wave(c, 0.5, 0.1)];
        let (output, grad) = (wave(len, 0.23, 1.0), wave(len, 0.11, 1.0));
        // (statistics, gradients) and each call's kernels on `device`.
        let run = |device: &Device| {
            let tensor = |values: &[f32], shape: Vec<usize>| {
                Tensor::<4>::from_data(TensorData::new(values.to_vec(), shape), device)
                    .into_dispatch()
            };
            let channel = |values: &[f32]| {
                Tensor::<1>::from_data(TensorData::new(values.to_vec(), [c]), device)
                    .into_dispatch()
            };
            // `x`'s values in [n, c, h, w] order, or stored [n, h, w, c] and read through
            // strides.
            let nhwc: Vec<f32> = (0..len)
                .map(|i| {
                    let (k, rest) = (i % c, i / c);
                    let (xx, rest) = (rest % w, rest / w);
                    let (y, b) = (rest % h, rest / h);
                    x[((b * c + k) * h + y) * w + xx]
                })
                .collect();
            let x_t = || match channels_last {
                true => Tensor::<4>::from_dispatch(tensor(&nhwc, vec![n, h, w, c]))
                    .permute([0, 3, 1, 2])
                    .into_dispatch(),
                false => tensor(&x, vec![n, c, h, w]),
            };
            let ((mean, variance, running_mean, running_variance), statistics_kernels) =
                qnet::kernels::count(device, || {
                    let [mean, variance] = running.each_ref().map(|r| channel(r));
                    Dispatch::norm_statistics(x_t(), mean, variance, 0.1)
                });
            let ((x_grad, gamma_grad, beta_grad), grads_kernels) =
                qnet::kernels::count(device, || {
                    Dispatch::norm_relu_train_grads(
                        x_t(),
                        channel(&gamma),
                        mean.clone(),
                        variance.clone(),
                        epsilon,
                        tensor(&output, vec![n, c, h, w]),
                        tensor(&grad, vec![n, c, h, w]),
                    )
                });
            let values = |t| {
                Tensor::<1>::from_dispatch(t)
                    .flatten::<1>(0, 0)
                    .into_data()
                    .try_to_vec::<f32>()
                    .unwrap()
            };
            (
                [mean, variance, running_mean, running_variance].map(values),
                [x_grad, gamma_grad, beta_grad].map(values),
                [statistics_kernels, grads_kernels],
            )
        };
        let (statistics, grads, kernels) = run(&gpu);
        let (want_statistics, want_grads, _) = run(&Device::flex());
        for (what, got, want) in [
            ("mean", &statistics[0], &want_statistics[0]),
            ("variance", &statistics[1], &want_statistics[1]),
            ("the running mean", &statistics[2], &want_statistics[2]),
            ("the running variance", &statistics[3], &want_statistics[3]),
            ("the input's gradient", &grads[0], &want_grads[0]),
            ("gamma's gradient", &grads[1], &want_grads[1]),
            ("beta's gradient", &grads[2], &want_grads[2]),
        ] {
            let d = Difference::between(got, want);
            println!("batch norm {:?}, {what}, wgpu vs cpu: {d:?}", [n, c, h, w]);
            assert!(d.max_rel <= 1e-5, "{what}: {d:?}");
        }
        for (call, launches) in ["statistics", "gradients"].iter().zip(kernels) {
            let launches = launches.expect("a wgpu device counts its launches");
            println!("batch norm {call}: {:?}", launches.by_name());
            assert_eq!(launches.total(), 1, "{call}: {:?}", launches.by_name());
        }
    }
}

/// The values at the executed pixels (qnet::plane_sums: each item's planes times its
/// weights, summed) and their gradient on the GPU are a kernel each and must give the CPU's
/// values: for maps laid out channels last, as the head convolution hands them over, and
/// for two heads.
#[test]
fn the_weighted_plane_sums_and_their_gradient_are_the_cpus_in_a_kernel_each() {
    use burn::backend::Dispatch;
    use qnet::plane_sums::PlaneSumBackend;

    let _turn = device_turn();
    let gpu = gpu();
    for [n, heads, s] in [[8, 1, 14], [5, 2, 9]] {
        // (sums, gradient, each call's kernels)
        let run = |device: &Device| {
            // The maps stored [n, s, s, heads] and read through strides as [n, heads, s, s].
            let maps = wavy([n, s, s, heads], 0.0, device).permute([0, 3, 1, 2]);
            let weights = wavy([n, 1, s, s], 1.0, device);
            let grad = wavy([n, heads], 2.0, device);
            let (sums, sums_kernels) = qnet::kernels::count(device, || {
                Dispatch::weighted_plane_sums(
                    maps.clone().into_dispatch(),
                    weights.clone().into_dispatch(),
                )
            });
            let (maps_grad, grad_kernels) = qnet::kernels::count(device, || {
                Dispatch::weighted_plane_sums_grad(
                    maps.clone().into_dispatch(),
                    weights.into_dispatch(),
                    grad.into_dispatch(),
                )
            });
            let maps_grad = Tensor::<4>::from_dispatch(maps_grad);
            let values = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
            (
                values(Tensor::<2>::from_dispatch(sums).unsqueeze()),
                values(maps_grad),
                [sums_kernels, grad_kernels],
            )
        };
        let (sums, maps_grad, kernels) = run(&gpu);
        let (want_sums, want_grad, _) = run(&Device::flex());
        for (what, got, want) in [
            ("sums", &sums, &want_sums),
            ("gradient", &maps_grad, &want_grad),
        ] {
            let d = Difference::between(got, want);
            println!("plane sums {:?}, {what}, wgpu vs cpu: {d:?}", [n, heads, s]);
            assert!(d.max_rel <= 1e-5, "{what}: {d:?}");
        }
        for (call, launches) in ["sums", "gradient"].iter().zip(kernels) {
            let launches = launches.expect("a wgpu device counts its launches");
            println!("plane sums {call}: {:?}", launches.by_name());
            assert_eq!(launches.total(), 1, "{call}: {:?}", launches.by_name());
        }
    }
}

#[test]
fn a_checkpoint_saved_on_one_backend_loads_on_the_other() {
    let _turn = device_turn();
    let gpu = gpu();
    let input = scene_input(2);
    let [_, net, _] = net_shapes();
    let dir = tempfile::tempdir().unwrap();
    let save = |trainer: &Trainer, name: &str| -> SavedNets {
        let (weights, trained) = trainer.checkpoint_weights().unwrap();
        let checkpoint = Checkpoint::at(dir.path().join(name));
        let manifest = Manifest {
            stage: 1,
            updates: trainer.updates(),
            side: input.side,
            config_hash: learner::checkpoint::config_hash(&net),
        };
        checkpoint
            .save(&SavedNets {
                manifest,
                weights,
                trained,
            })
            .unwrap();
        checkpoint
            .load(&learner::checkpoint::config_hash(&net))
            .unwrap()
    };
    let batch = samples(&input, 4);
    for (from, to, name) in [
        (gpu.clone(), Device::flex(), "wgpu-to-cpu"),
        (Device::flex(), gpu.clone(), "cpu-to-wgpu"),
    ] {
        let mut source = trainer(QNets::new(&net, &from), &net, input.side, &from);
        source.train_step(&batch).unwrap();
        let saved = save(&source, name);
        let mut resumed = trainer(QNets::new(&net, &to), &net, input.side, &to);
        resumed.resume(&saved).unwrap();
        assert_eq!(resumed.updates(), 1, "{name}");
        maps_agree(
            &resumed.published_nets(),
            &source.published_nets(),
            &net,
            &input,
            (name, AGREEMENT),
        );
    }
}

#[test]
fn a_short_run_trains_its_learner_on_wgpu() {
    let _turn = device_turn();
    let logs = tempfile::tempdir().unwrap();
    let logs_arg = logs.path().to_str().unwrap();
    let config = stage1::stage1_with(
        logs.path(),
        "wgpu",
        &[
            ("episodes", 200.into()),
            ("learner.checkpoint_every", 2.into()),
            ("backend.learner", "wgpu".into()),
        ],
    );
    let out = pushgrasp_ok(&[
        "train",
        "--config",
        config.to_str().unwrap(),
        "--logs",
        logs_arg,
        "--run-id",
        "wgpu",
        "--updates",
        "4",
    ]);
    println!("{out}");
    assert!(
        out.contains("the learner's nets on wgpu: "),
        "no adapter printed:\n{out}"
    );
    let run = logs.path().join("wgpu");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap();
    let updates = summary["learner"]["updates"].as_u64().unwrap();
    assert!(
        updates >= 4,
        "the learner stopped short of its budget: {summary}"
    );
    assert_eq!(summary["faults"], serde_json::json!([]), "{summary}");
    // The learner warmed up on its device before its first batch.
    assert!(
        summary["learner"]["warm_up_s"].as_f64().unwrap() > 0.0,
        "{summary}"
    );
    assert!(
        summary["failure"].is_null(),
        "the run failed: {}",
        summary["failure"]
    );
    assert!(run.join("checkpoint/manifest.toml").exists());
    // The learner's log names the adapter; an actor's names the CPU.
    let learner_log = mcaplog::read_summary(run.join("learner.mcap")).unwrap();
    let device = learner_log
        .metadata("device")
        .expect("the learner's device");
    assert_eq!(device["backend"], "wgpu");
    assert!(!device["adapter"].is_empty());
    let actor_log = mcaplog::read_summary(run.join("actor-0-0.mcap")).unwrap();
    assert_eq!(actor_log.metadata("device").unwrap()["backend"], "cpu");
    // The checkpoint the wgpu learner wrote acts on the CPU.
    pushgrasp_ok(&[
        "eval",
        "--checkpoint",
        run.join("checkpoint").to_str().unwrap(),
        "--random",
        "5",
        "--runs",
        "2",
        "--json",
    ]);
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(config.contains("learner = \"wgpu\""), "{config}");
}

#[test]
fn the_learner_bench_reports_the_adapter_and_its_agreement_with_the_cpu() {
    let _turn = device_turn();
    let out = pushgrasp_ok(&[
        "bench",
        "learner",
        "--backend",
        "wgpu",
        "--json",
        "--reps",
        "1",
        "--no-peer",
        "--sides",
        "112",
        "--peak-side",
        "128",
    ]);
    let figures: serde_json::Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    println!("{figures}");
    assert_eq!(figures["backend"], "wgpu");
    assert!(!figures["adapter"].as_str().unwrap().is_empty());
    let diff = figures["max_rel_diff_vs_cpu_112"].as_f64().unwrap();
    assert!(diff <= f64::from(AGREEMENT), "{diff}");
    assert!(figures["batch_train_speedup_vs_cpu_112"].as_f64().unwrap() > 0.0);
    // The kernels each timed call launches, counted as CubeCL issues them. A publication
    // reads the weights as they lie, so it may launch none.
    for (call, least) in [
        ("infer_16rot", 1.0),
        ("train_step", 1.0),
        ("batch_train", 1.0),
        ("publish", 0.0),
    ] {
        let kernels = figures[format!("{call}_kernels_112")].as_f64();
        assert!(kernels.is_some_and(|k| k >= least), "{call}: {kernels:?}");
    }
    // The host's CPU a step, by part: each part's threads found by their names.
    for part in ["fusion", "server", "other"] {
        let ms = figures[format!("batch_train_{part}_cpu_ms_112")].as_f64();
        assert!(ms.is_some_and(|ms| ms > 0.0), "{part}: {ms:?}");
    }

    let refused = pushgrasp_fails(&["bench", "learner", "--backend", "vulkan"]);
    assert!(refused.contains("cpu or wgpu"), "{refused}");
}

/// `bench e2e --learners cpu,wgpu`: the same real run with each learner, their paces and
/// the wgpu learner's against the CPU's. On lavapipe the wgpu learner is far the slower and
/// sets its run's pace, the rate limiter holding the actor back.
#[test]
fn the_end_to_end_bench_runs_the_gpu_learner_beside_the_cpus() {
    let _turn = device_turn();
    let out = pushgrasp_ok(&[
        "bench",
        "e2e",
        "--learners",
        "cpu,wgpu",
        "--environments",
        "1",
        "--episodes",
        "40",
        "--json",
    ]);
    let figures: serde_json::Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    println!("{figures}");
    let figure = |name: &str| {
        figures[name]
            .as_f64()
            .unwrap_or_else(|| panic!("no {name} in {figures}"))
    };
    for learner in ["_1", "_1_wgpu"] {
        assert!(figure(&format!("learner_updates_per_s{learner}")) > 0.0);
        let busy = figure(&format!("learner_busy_share{learner}"));
        assert!(busy > 0.0 && busy <= 1.0, "{figures}");
        assert!(
            figure(&format!("learner_updates_per_busy_s{learner}"))
                >= figure(&format!("learner_updates_per_s{learner}")),
            "{figures}"
        );
        // An update's busy time by part, the step's above nothing.
        assert!(figure(&format!("learner_step_ms_per_update{learner}")) > 0.0);
        assert!(figure(&format!("learner_rest_ms_per_update{learner}")) >= 0.0);
    }
    assert!(figure("learner_busy_share_1_wgpu") > 0.9, "{figures}");
    let speedup = figure("learner_speedup_1");
    let own = figure("learner_updates_per_busy_s_1_wgpu") / figure("learner_updates_per_busy_s_1");
    assert!((speedup - own).abs() <= 0.01 + 0.01 * own, "{figures}");
    assert!(figure("learner_rate_ratio_1") > 0.0);

    let refused = pushgrasp_fails(&["bench", "e2e", "--learners", "cuda"]);
    assert!(refused.contains("cpu or wgpu"), "{refused}");
}

/// `bench gpu`, the script for a GPU host, end to end with its sizes cut down: every
/// benchmark's figures in one file, each run's status beside them.
#[test]
fn the_gpu_bench_puts_every_figure_into_one_file() {
    let _turn = device_turn();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("gpu.json");
    pushgrasp_ok(&[
        "bench",
        "gpu",
        "--out",
        out.to_str().unwrap(),
        "--side",
        "56",
        "--paper-side",
        "56",
        "--reps",
        "1",
        "--e2e-episodes",
        "4",
        "--e2e-environments",
        "1",
        "--max-tasks",
        "16",
        // Cut down for a software device: the stage nets stand in for the paper-size ones.
        "--paper-config",
        "configs/stage1.toml",
        "--peak-side",
        "128",
    ]);
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    println!("{file:#}");
    let runs = file["runs"].as_array().unwrap();
    let names: Vec<&str> = runs.iter().map(|r| r["name"].as_str().unwrap()).collect();
    let learners = [
        "learner",
        "learner_stage",
        "learner_paper_size",
        "learner_max_tasks_16",
    ];
    assert_eq!(names.len(), 5, "{names:?}");
    for run in runs {
        assert_eq!(run["status"], "done", "{run}");
    }
    for name in learners {
        let figures = &file[name];
        assert_eq!(figures["backend"], "wgpu", "{name}");
        // PyTorch's step on CUDA beside ours, or why it did not run (no CUDA here).
        let torch = figures["torch"].as_str();
        assert!(
            figures["torch_device"].is_string() || torch.is_some_and(|t| t.starts_with("not run")),
            "{name}: {figures}"
        );
        for figure in [
            "batch_train_step_ms_56",
            "batch_train_kernels_56",
            "infer_16rot_kernels_56",
        ] {
            assert!(
                figures[figure].as_f64().is_some_and(|v| v > 0.0),
                "{name}: {figure}"
            );
        }
    }
    assert_eq!(
        file["learner_paper_size"]["trunk_widths"],
        serde_json::json!([8, 16])
    );
    // Too short a run for its learners to update (the test above runs one that does).
    assert_eq!(file["e2e"]["episodes_per_run"], 4);
    assert!(
        file["e2e"]["actions_per_s_1_wgpu"]
            .as_f64()
            .is_some_and(|v| v > 0.0)
    );
    let tasks = &runs[4]["env"][0];
    assert_eq!(tasks, "CUBECL_WGPU_MAX_TASKS=16");

    // A budget spent: the running benchmark stopped, the rest skipped, the file written.
    pushgrasp_ok(&[
        "bench",
        "gpu",
        "--out",
        out.to_str().unwrap(),
        "--budget-s",
        "1",
    ]);
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let statuses: Vec<&str> = file["runs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["status"].as_str().unwrap())
        .collect();
    assert!(
        statuses[0].starts_with("stopped at the budget's end"),
        "{statuses:?}"
    );
    assert!(
        statuses[1..].iter().all(|s| s.starts_with("skipped")),
        "{statuses:?}"
    );
    assert!(file.get("learner").is_none());
}

/// What `train` with its actors on wgpu says, under `env`, when it is refused before
/// anything starts (no run directory made).
fn refused_with(env: &[(&str, &str)]) -> String {
    let _turn = device_turn();
    let logs = tempfile::tempdir().unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_pushgrasp"))
        .args([
            "train",
            "--set",
            "backend.actors=\"wgpu\"",
            "--run-id",
            "none",
            "--logs",
        ])
        .arg(logs.path())
        // The machine's own choice of adapter, if any, stays out: each test sets its own.
        .env_remove("CUBECL_WGPU_DEFAULT_DEVICE")
        .envs(env.iter().copied())
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let error = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(!output.status.success());
    assert!(
        error.contains("backend.actors = \"wgpu\" (--backend)"),
        "{error}"
    );
    assert!(
        !logs.path().join("none").exists(),
        "a run directory was made"
    );
    error
}

#[test]
fn a_machine_without_an_adapter_is_refused_before_anything_starts() {
    // No Vulkan driver, no EGL vendor: wgpu finds no adapter at all.
    let error = refused_with(&[
        ("VK_ICD_FILENAMES", "/nonexistent.json"),
        ("__EGL_VENDOR_LIBRARY_FILENAMES", "/nonexistent.json"),
    ]);
    // What to install: the loader, NVIDIA's driver's dependency, and the software device.
    for package in ["libvulkan1", "libglvnd0", "mesa-vulkan-drivers"] {
        assert!(error.contains(package), "{package}: {error}");
    }
}

#[test]
fn an_adapter_chosen_that_the_machine_lacks_is_refused_naming_the_choice() {
    // The variable, not the machine's drivers, is what to check.
    let error = refused_with(&[("CUBECL_WGPU_DEFAULT_DEVICE", "DiscreteGpu(7)")]);
    assert!(
        error.contains("CUBECL_WGPU_DEFAULT_DEVICE=\"DiscreteGpu(7)\" chooses the adapter"),
        "{error}"
    );
    assert!(error.contains("IntegratedGpu(N)"), "{error}");
    assert!(!error.contains("libvulkan1"), "{error}");
}
