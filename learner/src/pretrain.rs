//! Generic visual pretraining of the trunks from the simulator's free labels. Each net, on
//! random rotations of random scenes (packed clusters among them), learns to mark every
//! object's outline, the boundaries between flush neighbours included, which the depth
//! plane alone does not show. Only the trunks are kept: the heads start afresh, as the
//! paper's trunks came pretrained on ImageNet and never saw a grasp or push outcome.

use burn::module::Module;
use burn::nn::loss::BinaryCrossEntropyLossConfig;
use burn::optim::GradientsParams;
use burn::prelude::*;
use qnet::{Geometry, NetInput, QNetConfig, QNets};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use sim::{Camera, Heightmaps, Primitive, ROTATIONS, Rows, SimConfig, SimError, Tabletop};

use crate::adam::Adam;
use crate::error::LearnerError;

/// Every setting of a pretraining, visible.
#[derive(Clone, Debug, PartialEq)]
pub struct PretrainConfig {
    /// Random scenes drawn before training; each update's items come from them.
    pub scenes: usize,
    /// Objects dropped in each scene; every other scene first lays four of them flush in two
    /// lines (a packed cluster, as in the challenging arrangements).
    pub objects: usize,
    /// Updates; each trains both nets on `batch` items.
    pub steps: usize,
    pub batch: usize,
    /// Adam's step size.
    pub learning_rate: f64,
    /// Scenes, rotations and the objects whose mask fills the goal plane derive from it.
    pub seed: u64,
}

impl Default for PretrainConfig {
    fn default() -> Self {
        Self {
            scenes: 200,
            objects: 10,
            steps: 1500,
            batch: 4,
            learning_rate: 1e-3,
            // Far from the seeds training and evaluation draw scenes from.
            seed: 3 << 40,
        }
    }
}

/// How a pretraining went, in the loss both nets' outline maps take (binary cross-entropy
/// per pixel, the two nets' mean).
#[derive(Clone, Debug, PartialEq)]
pub struct PretrainReport {
    /// The share of pixels on an outline.
    pub outline_share: f32,
    /// The loss of a map that says that share everywhere: what learning must beat.
    pub constant_loss: f32,
    /// The mean loss of the first and of the last `REPORT_WINDOW` updates.
    pub first_loss: f32,
    pub last_loss: f32,
}

/// Updates averaged at each end of the loss curve.
const REPORT_WINDOW: usize = 20;

/// 1 on each object pixel with a 4-neighbour of another id (another object or the table),
/// else 0: the outline, flush neighbours' shared boundary included.
pub fn outline(maps: &Heightmaps) -> Vec<f32> {
    let side = maps.side();
    let id = |row: usize, col: usize| maps.ids[maps.index(row, col)];
    let mut marks = vec![0.0; side * side];
    for row in 0..side {
        for col in 0..side {
            let here = id(row, col);
            let neighbours = [
                (row > 0).then(|| id(row - 1, col)),
                (row + 1 < side).then(|| id(row + 1, col)),
                (col > 0).then(|| id(row, col - 1)),
                (col + 1 < side).then(|| id(row, col + 1)),
            ];
            if here != 0 && neighbours.into_iter().flatten().any(|other| other != here) {
                marks[maps.index(row, col)] = 1.0;
            }
        }
    }
    marks
}

/// Pretrains both nets' trunks on `config.scenes` random scenes of `sim`, then returns them
/// in inference form with fresh heads. `progress` hears each update's loss.
pub fn pretrain(
    nets: QNets,
    net_config: &QNetConfig,
    sim: &SimConfig,
    config: &PretrainConfig,
    mut progress: impl FnMut(usize, f32),
) -> Result<(QNets, PretrainReport), LearnerError> {
    let camera = Camera::new(sim.grid()?);
    let scenes: Vec<(Heightmaps, Vec<f32>)> = (0..config.scenes)
        .into_par_iter()
        .map(|i| {
            let rows = if i % 2 == 1 {
                Rows {
                    blocks: 4,
                    lines: 2,
                }
            } else {
                Rows::NONE
            };
            let seed = config.seed.wrapping_add(i as u64);
            let (tabletop, _) = Tabletop::random_with_rows(sim, config.objects, rows, seed)?;
            let maps = camera.render(&tabletop);
            let marks = outline(&maps);
            Ok((maps, marks))
        })
        .collect::<Result<_, SimError>>()?;
    let pixels: usize = scenes.iter().map(|(_, marks)| marks.len()).sum();
    let marked: f32 = scenes.iter().flat_map(|(_, marks)| marks).sum();
    let share = marked / pixels.max(1) as f32;

    let device = nets.device().autodiff();
    let mut nets = nets.to_device(&device).train();
    let geometry = Geometry::new(camera.grid().side(), net_config);
    // Adam with burn's default factors, no weight decay.
    let mut optimiser = Adam::new(0.9, 0.999, 0.0);
    let loss_of = BinaryCrossEntropyLossConfig::new()
        .with_logits(true)
        .init(&device);
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut losses = Vec::with_capacity(config.steps);
    for step in 0..config.steps {
        let mut total = Tensor::<1>::zeros([1], &device);
        for primitive in [Primitive::Grasp, Primitive::Push] {
            let drawn: Vec<(usize, NetInput, u8)> = (0..config.batch)
                .map(|_| {
                    let scene = rng.random_range(0..scenes.len());
                    let maps = &scenes[scene].0;
                    let visible = maps.visible_ids();
                    let goal = if visible.is_empty() {
                        0
                    } else {
                        visible[rng.random_range(0..visible.len())]
                    };
                    let rotation = rng.random_range(0..ROTATIONS);
                    (scene, NetInput::encode(maps, goal), rotation)
                })
                .collect();
            let items: Vec<(&NetInput, u8)> = drawn.iter().map(|(_, i, k)| (i, *k)).collect();
            let logits = nets.q_maps(primitive, &items, &geometry)?;
            let n: usize = logits.dims().iter().product();
            let targets: Vec<i64> = drawn
                .iter()
                .flat_map(|(scene, _, _)| scenes[*scene].1.iter().map(|&m| m as i64))
                .collect();
            let targets = Tensor::<1, Int>::from_data(TensorData::new(targets, [n]), &device);
            total = total + loss_of.forward(logits.reshape([n]), targets);
        }
        let loss = total / 2.0;
        let value = loss.clone().into_scalar::<f32>();
        let grads = GradientsParams::from_grads(loss.backward(), &nets);
        nets = optimiser.step(config.learning_rate, nets, grads);
        losses.push(value);
        progress(step, value);
    }

    let window = |part: &[f32]| part.iter().sum::<f32>() / part.len().max(1) as f32;
    let ends = REPORT_WINDOW.min(losses.len());
    let report = PretrainReport {
        outline_share: share,
        constant_loss: -(share * share.ln() + (1.0 - share) * (1.0 - share).ln()),
        first_loss: window(&losses[..ends]),
        last_loss: window(&losses[losses.len() - ends..]),
    };
    Ok((nets.valid().with_fresh_heads(net_config), report))
}

#[cfg(test)]
mod tests {
    use qnet::Device;
    use sim::PixelGrid;

    use super::*;

    #[test]
    fn the_outline_marks_the_boundary_between_flush_neighbours_and_nothing_inside() {
        let mut maps = Heightmaps::new(PixelGrid::new(0.004).unwrap());
        // Two 10 x 10 blocks side by side, touching along column 19 | 20.
        for row in 10..20 {
            for col in 10..30 {
                let i = maps.index(row, col);
                maps.ids[i] = if col < 20 { 1 } else { 2 };
            }
        }
        let marks = outline(&maps);
        let at = |row, col| marks[maps.index(row, col)];
        assert_eq!((at(15, 19), at(15, 20)), (1.0, 1.0), "the shared boundary");
        assert_eq!(
            (at(10, 15), at(19, 25), at(15, 10)),
            (1.0, 1.0, 1.0),
            "edges"
        );
        assert_eq!((at(15, 15), at(15, 25)), (0.0, 0.0), "insides");
        assert_eq!(
            (at(9, 15), at(15, 30), at(5, 5)),
            (0.0, 0.0, 0.0),
            "the table"
        );
        assert_eq!(marks.iter().sum::<f32>(), (2 * (10 + 10 + 8 + 8)) as f32);
    }

    #[test]
    fn pretraining_learns_the_outlines() {
        let sim = SimConfig {
            pixel_size: 0.004,
            ..SimConfig::default()
        };
        let net_config = QNetConfig::default();
        let config = PretrainConfig {
            scenes: 4,
            steps: 60,
            batch: 2,
            ..PretrainConfig::default()
        };
        let device = Device::flex();
        device.seed(1);
        let nets = QNets::new(&net_config, &device);
        let mut heard = 0;
        let (_, report) = pretrain(nets, &net_config, &sim, &config, |_, loss| {
            assert!(loss.is_finite());
            heard += 1;
        })
        .unwrap();
        assert_eq!(heard, 60);
        assert!(
            report.outline_share > 0.01 && report.outline_share < 0.2,
            "{report:?}"
        );
        assert!(report.last_loss < 0.7 * report.first_loss, "{report:?}");
    }
}
