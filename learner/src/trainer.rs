//! One learner update: the Q value at each sample's executed pixel (and, for a grasp, the
//! same pixel at the symmetric rotation k + 8: a parallel jaw is symmetric; with
//! `mirror_grasps`, also the grasp's mirror image; with `translate_samples`, also the
//! sample moved a few pixels; with `spot_q`, also where a grasp's Q map peaks outside its
//! goal, at label 0), the Huber loss against the label weighted by the replay's
//! importance-sampling weight, and an Adam step on the net being trained. With an outcome
//! head on the grasp net, its cross-entropy against the grasp's outcome at the same pixels is
//! added. Every other pixel contributes nothing.
//!
//! The training step is one computation (targets, losses, weights, the Adam step) whose parts share
//! the trainer's state, so they stay in one file; the losses themselves, functions of the
//! step's values alone, are `crate::loss`.

use burn::module::Module;
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::Transaction;
use policy::QMaps;
use qnet::{Geometry, NetInput, QNetConfig, QNets};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sim::{Action, Primitive, ROTATIONS};

use crate::adam::Adam;
use crate::averaging::polyak_step;
use crate::checkpoint::SavedNets;
use crate::config::LearningConfig;
use crate::error::LearnerError;
use crate::items::{Item, taught_items};
use crate::loss::{executed_pixel_loss, outcome_loss};
use crate::targets::{NextState, double_q_values};

/// One transition to learn from.
#[derive(Clone, Debug)]
pub struct Sample {
    /// The observation the action was chosen on, with the sample's goal.
    pub input: NetInput,
    pub action: Action,
    /// The bootstrap label (`policy::label`).
    pub label: f32,
    /// The replay's importance-sampling weight (1 without prioritisation).
    pub weight: f32,
    /// Whether the action was a grasp that took the goal (false for a push): what the
    /// grasp net's outcome head learns.
    pub succeeded: bool,
}

/// Which net an update trains; the other is frozen whole (trunks and head).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TrainedNet {
    Grasp,
    Push,
}

impl TrainedNet {
    pub fn primitive(self) -> Primitive {
        match self {
            TrainedNet::Grasp => Primitive::Grasp,
            TrainedNet::Push => Primitive::Push,
        }
    }
}

/// What an update did.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    /// The weighted loss summed over the batch (before the step).
    pub loss: f32,
    /// Each sample's Q at its executed pixel before the step.
    pub predicted: Vec<f32>,
    /// |label - predicted| per sample: the new priorities.
    pub td_errors: Vec<f32>,
}

/// The nets being trained, their optimiser, and which of them learns.
#[derive(Clone)]
pub struct Trainer {
    nets: QNets,
    /// The Polyak average of `nets` in inference form, when the config averages.
    average: Option<QNets>,
    /// The target nets of the learner's bootstrap values, in inference form, when the config
    /// computes them: `nets` as they were after the last multiple of `target_update_every`
    /// updates (or when their weights were last loaded).
    target: Option<QNets>,
    optimiser: Adam,
    geometry: Geometry,
    config: LearningConfig,
    trained: TrainedNet,
    updates: u64,
    /// Whether the nets train on the CPU backend (whose steps run on rayon's pool).
    on_cpu: bool,
}

impl Trainer {
    /// A trainer for `side x side` heightmaps. `nets` move to the autodiff version of
    /// `device`.
    pub fn new(
        nets: QNets,
        net_config: &QNetConfig,
        side: usize,
        config: &LearningConfig,
        trained: TrainedNet,
        device: &Device,
    ) -> Self {
        let optimiser = Adam::of(config);
        let on_cpu = device.clone().without_autodiff() == Device::flex();
        let nets = nets.to_device(&device.clone().autodiff()).train();
        let average = (config.polyak_rate < 1.0).then(|| nets.valid());
        let target = (config.target_update_every > 0).then(|| nets.valid());
        let mut trainer = Self {
            nets: nets.clone(),
            average,
            target,
            optimiser,
            geometry: Geometry::new(side, net_config),
            config: config.clone(),
            trained,
            updates: 0,
            on_cpu,
        };
        trainer.hold(nets);
        trainer
    }

    /// Trains `nets` (on the trainer's autodiff device) from now on, `self.trained` of them.
    /// On a GPU their convolution weights are first laid out channels-last, as the GPU
    /// convolves them; Adam keeps each parameter laid out as it lies, so no weight is copied
    /// before a convolution or its input's gradient (results/gpu.md, "Weights held
    /// channels-last in training"); a rotation-equivariant net's full kernels are gathered
    /// from them channels-last too (`qnet::equivariant::expand`).
    fn hold(&mut self, nets: QNets) {
        self.nets = if self.on_cpu {
            nets
        } else {
            nets.with_weights_channels_last()
        };
        self.set_trained(self.trained);
    }

    /// Trains `which` from now on, freezing the other net whole.
    pub fn set_trained(&mut self, which: TrainedNet) {
        let nets = self.nets.clone();
        self.nets = match which {
            TrainedNet::Grasp => QNets {
                push: nets.push.freeze(),
                grasp: nets.grasp.unfreeze(),
            },
            TrainedNet::Push => QNets {
                push: nets.push.unfreeze(),
                grasp: nets.grasp.freeze(),
            },
        };
        self.trained = which;
    }

    pub fn trained(&self) -> TrainedNet {
        self.trained
    }

    /// Updates taken so far in the run (a resumed run counts on from its checkpoint).
    pub fn updates(&self) -> u64 {
        self.updates
    }

    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// The nets to publish to actors, for acting and their bootstrap values, in inference
    /// form (no autodiff, batch norm on its running statistics): the Polyak average when the
    /// config averages and publishes it, else the trained nets.
    pub fn published_nets(&self) -> QNets {
        match &self.average {
            Some(average) if self.config.publish_average => average.clone(),
            _ => self.nets.valid(),
        }
    }

    /// What a checkpoint holds: the nets to use (the Polyak average when the config
    /// averages, else the trained nets), and the trained nets when those are the average.
    pub fn checkpoint_weights(&self) -> Result<(Vec<u8>, Option<Vec<u8>>), LearnerError> {
        Ok(match &self.average {
            Some(average) => (average.to_bytes()?, Some(self.nets.valid().to_bytes()?)),
            None => (self.nets.valid().to_bytes()?, None),
        })
    }

    /// The step size of the next update: `learning_rate`, falling geometrically to the
    /// decay's end over its updates when the config decays it.
    pub fn learning_rate(&self) -> f64 {
        let start = self.config.learning_rate;
        match &self.config.lr_decay {
            Some(decay) if decay.over_updates > 0 => {
                let done = (self.updates as f64 / decay.over_updates as f64).min(1.0);
                start * (decay.to / start).powf(done)
            }
            _ => start,
        }
    }

    /// One update on a batch of samples of the trained net's primitive.
    pub fn train_step(&mut self, samples: &[Sample]) -> Result<StepReport, LearnerError> {
        // On the CPU, on rayon's pool: the step's parallel operations then start from a
        // worker instead of each being handed over from this thread and waited for (a futex
        // wake and sleep per operation, a sixth of a one-grasp step on two cores). On a GPU,
        // on this thread: burn's fusion queues a thread's operations on a stream of its own,
        // and a worker's stream holds the backward pass and the optimiser, unrun, until a
        // later read needs them, out of reach of this thread's device syncs.
        if self.on_cpu {
            rayon::scope(|_| self.update(samples))
        } else {
            self.update(samples)
        }
    }

    fn update(&mut self, samples: &[Sample]) -> Result<StepReport, LearnerError> {
        let primitive = self.trained.primitive();
        if let Some(other) = samples.iter().find(|s| s.action.primitive != primitive) {
            return Err(LearnerError::Frozen(other.action.primitive));
        }
        let mirrors: Vec<NetInput> = if primitive == Primitive::Grasp && self.config.mirror_grasps {
            samples.iter().map(|s| s.input.mirrored()).collect()
        } else {
            Vec::new()
        };
        let translated: Vec<(NetInput, (isize, isize))> = samples
            .iter()
            .zip(self.shifts(samples))
            .map(|(s, (rows, cols))| (s.input.translated(rows, cols), (rows, cols)))
            .collect();
        let items: Vec<Vec<Item>> = samples
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let moved = translated.get(i).map(|(input, shift)| (input, *shift));
                taught_items(&s.input, s.action, mirrors.get(i), moved)
            })
            .collect();
        let per_sample = items.first().map_or(1, Vec::len);
        let mut items: Vec<Item> = items.into_iter().flatten().collect();
        let own_items = items.len();
        // SPOT-Q's items last: a grasp at each sample's peak (both of its rotations), label 0.
        let spots: Vec<(usize, usize)> = self
            .spot_grasps(samples)?
            .into_iter()
            .map(|(i, peak)| {
                let peak = taught_items(&samples[i].input, peak, None, None);
                let count = peak.len();
                items.extend(peak);
                (i, count)
            })
            .collect();
        let inputs: Vec<(&NetInput, u8)> = items.iter().map(|i| (i.input, i.rotation)).collect();
        let pixels: Vec<(usize, usize)> = items.iter().map(|i| i.pixel).collect();
        let (q, logits) = self
            .nets
            .at_pixels(primitive, &inputs, &pixels, &self.geometry)?;

        // Per item: each sample's value for its own items, then `spot`'s for its SPOT-Q item.
        let repeat = |f: &dyn Fn(&Sample) -> f32, spot: &dyn Fn(&Sample) -> f32| -> Vec<f32> {
            samples
                .iter()
                .flat_map(|s| std::iter::repeat_n(f(s), per_sample))
                .chain(
                    spots
                        .iter()
                        .flat_map(|&(i, count)| std::iter::repeat_n(spot(&samples[i]), count)),
                )
                .collect()
        };
        let labels = repeat(&|s| s.label, &|_| 0.0);
        let weights = repeat(&|s| s.weight, &|s| s.weight);
        let mut loss = executed_pixel_loss(q.clone(), &labels, &weights, self.config.huber_delta);
        if let Some(logits) = logits {
            let succeeded = repeat(&|s| f32::from(u8::from(s.succeeded)), &|_| 0.0);
            let outcome = outcome_loss(logits, &succeeded, &weights);
            loss = loss + outcome.mul_scalar(self.config.outcome_loss_weight);
        }

        // Both read in one transfer, before the backward pass: a GPU waits once. (Read after
        // the optimiser step instead, burn's fusion ran 27 more of the loss's small
        // operations as kernels of their own in a step of the stage nets.)
        let [q_values, loss_value] = Transaction::default()
            .register(q.clone())
            .register(loss.clone())
            .execute()
            .try_into()
            .expect("two reads");
        let q_values = q_values.try_into_vec::<f32>().expect("f32 Q values");
        let loss_value = loss_value.try_into_vec::<f32>().expect("f32 loss")[0];
        let grads = GradientsParams::from_grads(loss.backward(), &self.nets);
        self.nets = self
            .optimiser
            .step(self.learning_rate(), self.nets.clone(), grads);
        self.updates += 1;
        if let Some(average) = self.average.take() {
            // A plain mean of the run's updates until there are 1 / rate of them.
            let rate = self.config.polyak_rate.max(1.0 / self.updates as f32);
            self.average = Some(polyak_step(average, &self.nets.valid(), rate));
        }
        if self.target.is_some() && self.updates.is_multiple_of(self.config.target_update_every) {
            self.target = Some(self.nets.valid());
        }

        // Report each sample's own rotation (the first of its items).
        let predicted: Vec<f32> = q_values[..own_items]
            .iter()
            .step_by(per_sample)
            .copied()
            .collect();
        let td_errors = samples
            .iter()
            .zip(&predicted)
            .map(|(s, q)| (s.label - q).abs())
            .collect();
        Ok(StepReport {
            loss: loss_value,
            predicted,
            td_errors,
        })
    }

    /// Each sample's translation (rows, columns) for this update when the config
    /// translates, else none: drawn uniformly from the shifts of at most
    /// `translate_samples` pixels a direction that move something and keep the sample's
    /// pixel on the map, from a generator seeded by the update's number (a resumed run
    /// draws on where it was).
    fn shifts(&self, samples: &[Sample]) -> Vec<(isize, isize)> {
        let reach = self.config.translate_samples as isize;
        if reach == 0 {
            return Vec::new();
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.updates);
        samples
            .iter()
            .map(|s| {
                let side = s.input.side as isize;
                let (row, col) = (s.action.row as isize, s.action.col as isize);
                let on_map = |d: isize, at: isize| (0..side).contains(&(at + d));
                let shifts: Vec<(isize, isize)> = (-reach..=reach)
                    .flat_map(|dr| (-reach..=reach).map(move |dc| (dr, dc)))
                    .filter(|&(dr, dc)| (dr, dc) != (0, 0) && on_map(dr, row) && on_map(dc, col))
                    .collect();
                shifts[rng.random_range(0..shifts.len())]
            })
            .collect()
    }

    /// SPOT-Q's grasps when the config asks for them ([`LearningConfig::spot_q`]), as
    /// (sample, grasp): for each grasp sample whose goal is seen, the grasp at its executed
    /// rotation where the current nets' Q map there peaks, if that lies outside the goal
    /// mask. The nets in inference form, as the actors act with them.
    fn spot_grasps(&self, samples: &[Sample]) -> Result<Vec<(usize, Action)>, LearnerError> {
        if !self.config.spot_q || self.trained != TrainedNet::Grasp {
            return Ok(Vec::new());
        }
        let seen: Vec<usize> = (0..samples.len())
            .filter(|&i| samples[i].input.mask.iter().any(|&m| m > 0.0))
            .collect();
        if seen.is_empty() {
            return Ok(Vec::new());
        }
        let items: Vec<(&NetInput, u8)> = seen
            .iter()
            .map(|&i| (&samples[i].input, samples[i].action.rotation))
            .collect();
        let maps = self
            .nets
            .valid()
            .q_maps(Primitive::Grasp, &items, &self.geometry)?;
        let maps = maps.into_data().try_to_vec::<f32>().expect("f32 Q maps");
        let side = self.geometry.side();
        let everywhere = vec![true; side * side];
        let mut spots = Vec::new();
        for (i, map) in seen.into_iter().zip(maps.chunks_exact(side * side)) {
            let map = QMaps::new(1, side, map.to_vec()).expect("one map of side x side");
            let Some((_, _, row, col)) = map.best_where(&everywhere) else {
                continue;
            };
            if samples[i].input.mask[row * side + col] == 0.0 {
                spots.push((
                    i,
                    Action {
                        row,
                        col,
                        ..samples[i].action
                    },
                ));
            }
        }
        Ok(spots)
    }

    /// Starts from other weights (an earlier stage's nets), and restarts any average and
    /// the target nets from them.
    pub fn load_weights(&mut self, bytes: &[u8]) -> Result<(), LearnerError> {
        let loaded = self.nets.clone().load_bytes(bytes)?;
        self.hold(loaded);
        if self.average.is_some() {
            self.average = Some(self.nets.valid());
        }
        if self.target.is_some() {
            self.target = Some(self.nets.valid());
        }
        Ok(())
    }

    /// The learner's own values of next states ([`crate::targets`]) when the config computes
    /// them (`target_update_every` > 0), else `None`: the samples' labels then use their
    /// actors' values.
    pub fn next_values(&self, states: &[NextState]) -> Result<Option<Vec<f32>>, LearnerError> {
        let Some(target) = &self.target else {
            return Ok(None);
        };
        double_q_values(&self.nets.valid(), target, states, &self.geometry).map(Some)
    }

    /// Takes one update of each of `nets` on `batch` blank samples, and values `batch` blank
    /// next states when the config computes them, on a copy of this trainer: this one is
    /// left as it was. On a GPU the first use of each operation's shape tunes its kernels
    /// (CubeCL's autotune: seconds on a GPU, minutes on a software device, then kept on
    /// disk); warming up does that before training, where the caller can say so, instead of
    /// inside the first updates.
    pub fn warm_up(self, nets: &[TrainedNet], batch: usize) -> Result<(), LearnerError> {
        let side = self.geometry.side();
        let blank = NetInput {
            side,
            colour: vec![0.0; 3 * side * side],
            depth: vec![0.0; side * side],
            mask: vec![0.0; side * side],
        };
        let centre = side / 2;
        for &net in nets {
            let mut scratch = self.clone();
            scratch.set_trained(net);
            let samples: Vec<Sample> = (0..batch)
                .map(|i| Sample {
                    input: blank.clone(),
                    action: Action {
                        primitive: net.primitive(),
                        rotation: (i % usize::from(ROTATIONS)) as u8,
                        row: centre,
                        col: centre,
                    },
                    label: 0.0,
                    weight: 1.0,
                    succeeded: false,
                })
                .collect();
            scratch.train_step(&samples)?;
            let states: Vec<NextState> = (0..batch)
                .map(|_| NextState {
                    input: blank.clone(),
                    primitive: net.primitive(),
                    allowed: vec![true; side * side],
                })
                .collect();
            scratch.next_values(&states)?;
        }
        Ok(())
    }

    /// Continues a run from its checkpoint: the nets it holds, the trained nets when they
    /// were kept apart from an average, and the updates taken, so the average and the step
    /// size go on where they were.
    pub fn resume(&mut self, saved: &SavedNets) -> Result<(), LearnerError> {
        self.load_weights(saved.trained.as_deref().unwrap_or(&saved.weights))?;
        if self.average.is_some() {
            let average = self.nets.valid().load_bytes(&saved.weights)?;
            self.average = Some(average);
        }
        self.updates = saved.manifest.updates;
        Ok(())
    }
}
