//! The learner role: asks the buffer for batches, trains the stage's net on them, sends the
//! new priorities back, broadcasts weights every `publish_every` updates and checkpoints
//! every `checkpoint_every` and at shutdown.
//!
//! Two requests are kept in flight, so the buffer samples the next batch while this one
//! trains. The weights' version is the number of updates they come from (plus, after the
//! learner was restarted, what its predecessor published past the checkpoint resumed), so
//! it only grows, across `--resume` and restarts.
//!
//! The learner role is one loop: sampling, training, publishing and checkpointing in the order of
//! one update, with the ports it does them through.

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use experience::{BatchItem, Transition};
use learner::checkpoint::config_hash;
use learner::{Checkpoint, Manifest, NextState, Sample, SavedNets, Trainer};
use mcaplog::{LogLevel, RunLog};
use policy::{grasp_label, grasp_region, push_label, push_region};
use qnet::{Backend, NetInput, QNets};
use sim::Primitive;
use wire::{
    BatchMessage, Inbox, Message, Outbox, PriorityUpdate, Role, Status, Topic, Transport, Weights,
};

mod requests;

use super::stopwatch::Stopwatch;
use crate::{Lifeline, STATUS_EVERY, stop_requested};
use requests::Requests;
use rundir::LearnerReport;
use rundir::backend::open_device;
use rundir::config::RunConfig;
use rundir::record::{LEARNER_UPDATE, UpdateRecord};
use rundir::run_dir::{RunDir, keep_previous, newest_or_previous, previous};

/// The training sample of a stored transition: its label from reward and `next_value`, the
/// bootstrap value of its next state (`None` when the scene ended with it).
fn sample(transition: &Transition, next_value: Option<f32>, weight: f32, gamma: f32) -> Sample {
    let label = match transition.primitive() {
        Primitive::Grasp => grasp_label(
            transition.reward,
            transition.goal_grasped(),
            next_value,
            gamma,
        ),
        Primitive::Push => push_label(transition.reward, next_value, gamma),
    };
    Sample {
        input: NetInput::encode(&transition.obs, transition.goal),
        action: transition.action,
        label,
        weight,
        succeeded: transition.primitive() == Primitive::Grasp && transition.goal_grasped(),
    }
}

/// How this learner process starts.
#[derive(Clone, Copy, Debug)]
pub struct Start {
    /// From the run directory's checkpoint, if it holds one.
    pub resume: bool,
    /// 0, then one more for each restart of the learner in the run.
    pub incarnation: u32,
    /// The newest weight version published before this process (a restart's): the versions
    /// it publishes pass it, so actors never see one go back.
    pub weights_after: u64,
}

/// Trains until the launcher says stop; checkpoints and returns what it did. With `resume`,
/// starts from the run directory's checkpoint.
pub fn run(
    transport: &dyn Transport,
    config: &RunConfig,
    dir: &RunDir,
    start: Start,
    log: &RunLog,
    lifeline: &Lifeline,
) -> Result<LearnerReport> {
    let mut role = LearnerRole::new(config, log, dir)?;
    let warning = role.start_from(start.resume)?;
    role.continue_versions(start.weights_after);
    let mut ports = Ports::open(transport)?;
    if let Some(warning) = warning {
        crate::process_log::warn(&mut ports.status, log, Role::Learner, warning)?;
    }
    role.publish(&mut ports.weights)?;
    // Only a GPU backend tunes its kernels; the CPU's are chosen by shape.
    if config.backend.learner == Backend::Wgpu {
        role.warm_up(&mut ports.status, lifeline)?;
    }
    let mut asked = Requests::new(start.incarnation);
    let mut last_status = Instant::now();
    while !lifeline.lost() && !stop_requested(&mut ports.control, Role::Learner)? {
        asked.keep_in_flight(&mut ports.requests, config)?;
        match ports.batches.try_recv()? {
            Some(Message::Batch(batch)) => {
                if asked.answered(&batch)? {
                    role.learn(&batch, &mut ports)?;
                } else {
                    role.report.stale_batches += 1;
                }
            }
            Some(Message::BufferStarted(incarnation)) => {
                let lost = asked.forget();
                log.log_line(
                    LogLevel::Warning,
                    &format!("buffer {incarnation} started: asking again for {lost} batches"),
                )?;
            }
            Some(other) => bail!("the batches topic carried {other:?}"),
            None => std::thread::sleep(Duration::from_millis(1)),
        }
        if last_status.elapsed() >= STATUS_EVERY {
            // Actors that joined since the last broadcast get the newest weights now, not
            // only at the next one.
            ports.weights.refresh()?;
            ports.status.send(&role.status())?;
            last_status = Instant::now();
        }
    }
    role.finish(&mut ports.status, lifeline.own_process())
}

/// The learner's ends of the run's topics.
struct Ports {
    control: Inbox,
    batches: Inbox,
    requests: Outbox,
    weights: Outbox,
    status: Outbox,
}

impl Ports {
    fn open(transport: &dyn Transport) -> Result<Self> {
        Ok(Self {
            control: Inbox::open(transport, Topic::Control)?,
            batches: Inbox::open(transport, Topic::Batches)?,
            requests: Outbox::open(transport, Topic::Requests)?,
            weights: Outbox::open(transport, Topic::Weights)?,
            status: Outbox::open(transport, Topic::Status)?,
        })
    }
}

struct LearnerRole<'a> {
    config: &'a RunConfig,
    log: &'a RunLog,
    trainer: Trainer,
    checkpoint: Checkpoint,
    /// Updates before this process started (from the checkpoint resumed).
    updates_before: u64,
    /// When the first batch arrived.
    first_batch: Option<Stopwatch>,
    /// Added to the updates to give the weight version (after a restart, so versions keep
    /// rising past the dead learner's).
    version_offset: u64,
    report: LearnerReport,
}

impl<'a> LearnerRole<'a> {
    /// Fresh nets from the run's seed, on the learner's backend.
    fn new(config: &'a RunConfig, log: &'a RunLog, dir: &RunDir) -> Result<Self> {
        let device = open_device(config.backend.learner, "learner", log)?;
        // The initial weights come from the backend's generator.
        device.seed(config.seed);
        let nets = QNets::new(&config.net, &device);
        let trainer = Trainer::new(
            nets,
            &config.net,
            config.side(),
            &config.learning,
            config.trained_nets()[0],
            &device,
        );
        Ok(Self {
            config,
            log,
            trainer,
            checkpoint: Checkpoint::at(dir.checkpoint()),
            updates_before: 0,
            first_batch: None,
            version_offset: 0,
            report: LearnerReport::default(),
        })
    }

    /// After a restart: versions from here on pass `weights_after`, and the updates the
    /// dead learner took since the checkpoint this one resumed are counted as redone.
    fn continue_versions(&mut self, weights_after: u64) {
        if weights_after == 0 {
            return;
        }
        self.version_offset = (weights_after + 1).saturating_sub(self.updates());
        self.report.redone_updates = weights_after.saturating_sub(self.updates());
    }

    /// Continues from the run's checkpoint when resuming one that has it, else starts from
    /// `init_from`'s nets (an earlier stage's) if the config names them. Returns the warning
    /// when the newest checkpoint was damaged and the previous one was taken.
    fn start_from(&mut self, resume: bool) -> Result<Option<String>> {
        let config = self.config;
        let newest = self.checkpoint.dir().to_path_buf();
        let saved = [newest.clone(), previous(&newest)]
            .iter()
            .any(|dir| dir.join("manifest.toml").exists());
        if resume && saved {
            // A damaged newest checkpoint: the previous one, with a warning.
            let hash = config_hash(&config.net);
            let (saved, warning) = newest_or_previous(&newest, |before| {
                let dir = if before {
                    previous(&newest)
                } else {
                    newest.clone()
                };
                Ok(Checkpoint::at(dir).load(&hash)?)
            })?;
            let manifest = &saved.manifest;
            if manifest.stage != config.stage || manifest.side != config.side() {
                bail!(
                    "{}: the checkpoint is of stage {} at {} px; this run is stage {} at {} px",
                    self.checkpoint.dir().display(),
                    manifest.stage,
                    manifest.side,
                    config.stage,
                    config.side()
                );
            }
            self.trainer.resume(&saved)?;
            self.updates_before = manifest.updates;
            return Ok(warning);
        } else if let Some(init) = &config.init_from {
            // An earlier stage's nets: its weights, this stage's fresh update count.
            let saved = Checkpoint::at(init).load(&config_hash(&config.net))?;
            if saved.manifest.side != config.side() {
                bail!(
                    "init_from {}: the nets were trained at {} px; this run is at {} px",
                    init.display(),
                    saved.manifest.side,
                    config.side()
                );
            }
            self.trainer.load_weights(&saved.weights)?;
        }
        Ok(None)
    }

    fn updates(&self) -> u64 {
        self.trainer.updates()
    }

    /// One update on `batch` (none for an empty one), its priorities back to the buffer,
    /// and the weights and checkpoint when their turn comes.
    fn learn(&mut self, batch: &BatchMessage, ports: &mut Ports) -> Result<()> {
        if batch.items.is_empty() {
            self.report.empty_batches += 1;
            return Ok(());
        }
        self.first_batch.get_or_insert_with(Stopwatch::start);
        let started = Instant::now();
        let priorities = self.train(batch)?;
        ports.requests.send(&Message::PriorityUpdate(priorities))?;
        let updates = self.updates();
        if updates.is_multiple_of(self.config.learner.publish_every) {
            let publishing = Instant::now();
            self.publish(&mut ports.weights)?;
            self.report.publish_s += publishing.elapsed().as_secs_f64();
        }
        if updates.is_multiple_of(self.config.learner.checkpoint_every) {
            let saving = Instant::now();
            self.save_checkpoint()?;
            self.report.checkpoint_s += saving.elapsed().as_secs_f64();
        }
        self.report.busy_s += started.elapsed().as_secs_f64();
        Ok(())
    }

    fn publish(&mut self, weights: &mut Outbox) -> Result<()> {
        let version = self.updates() + self.version_offset;
        weights.send(&Message::Weights(Weights {
            version,
            stage: self.config.stage,
            bytes: self.trainer.published_nets().to_bytes()?,
        }))?;
        self.report.weights_version = version;
        Ok(())
    }

    fn save_checkpoint(&mut self) -> Result<()> {
        let (weights, trained) = self.trainer.checkpoint_weights()?;
        keep_previous(self.checkpoint.dir())?;
        self.checkpoint.save(&SavedNets {
            manifest: Manifest {
                stage: self.config.stage,
                updates: self.updates(),
                side: self.config.side(),
                config_hash: config_hash(&self.config.net),
            },
            weights,
            trained,
        })?;
        self.report.checkpoints += 1;
        Ok(())
    }

    /// One update on a batch; returns the new priorities.
    fn train(&mut self, batch: &BatchMessage) -> Result<PriorityUpdate> {
        let first = batch.items.first().expect("empty batches are skipped");
        let net = self
            .config
            .trained_nets()
            .iter()
            .find(|n| n.primitive() == first.transition.primitive())
            .copied();
        let Some(net) = net else {
            bail!(
                "stage {} does not train on {:?} transitions",
                self.config.stage,
                first.transition.primitive()
            );
        };
        if self.trainer.trained() != net {
            self.trainer.set_trained(net);
        }
        let gamma = self.config.learning.gamma;
        let items = buffer::unpack(&batch.items).context("a batch from the buffer")?;
        let samples: Vec<Sample> = items
            .iter()
            .zip(self.next_values(&items)?)
            .map(|(item, next_value)| sample(&item.transition, next_value, item.weight, gamma))
            .collect();
        let stepping = Instant::now();
        let step = self.trainer.train_step(&samples)?;
        self.report.step_s += stepping.elapsed().as_secs_f64();
        self.report.last_loss = Some(step.loss);
        let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len().max(1) as f32;
        self.log.json(
            LEARNER_UPDATE,
            &UpdateRecord {
                updates: self.updates(),
                primitive: format!("{:?}", net.primitive()).to_lowercase(),
                batch: samples.len(),
                loss: step.loss,
                mean_predicted_q: mean(&step.predicted),
                mean_td_error: mean(&step.td_errors),
            },
        )?;
        Ok(PriorityUpdate {
            updates: batch
                .items
                .iter()
                .zip(&step.td_errors)
                .map(|(item, td)| (item.key, f64::from(*td)))
                .collect(),
        })
    }

    /// Each item's bootstrap value of its next state: the learner's own for a push stored with
    /// its next step when the config computes them (`learning.target_update_every`), else
    /// the one its actor computed.
    fn next_values(&mut self, items: &[BatchItem]) -> Result<Vec<Option<f32>>> {
        let mut values: Vec<Option<f32>> = items.iter().map(|i| i.transition.next_value).collect();
        if self.config.learning.target_update_every == 0 {
            return Ok(values);
        }
        let (indices, states): (Vec<usize>, Vec<NextState>) = items
            .iter()
            .enumerate()
            .filter_map(|(i, item)| {
                let t = &item.transition;
                let next = t
                    .next
                    .as_ref()
                    .filter(|_| t.primitive() == Primitive::Push)?;
                let allowed = match next.primitive {
                    Primitive::Grasp => {
                        grasp_region(&next.obs, t.goal, self.config.policy.grasp_margin)
                    }
                    // Replay keeps the observation only: a finer landing view is not
                    // at hand here.
                    Primitive::Push => push_region(
                        &next.obs,
                        None,
                        t.goal,
                        &self.config.policy,
                        self.config.sim.push_length,
                    ),
                };
                let state = NextState {
                    input: NetInput::encode(&next.obs, t.goal),
                    primitive: next.primitive,
                    allowed,
                };
                Some((i, state))
            })
            .unzip();
        if let Some(learned) = self.trainer.next_values(&states)? {
            self.report.learned_next_values += learned.len() as u64;
            for (i, value) in indices.into_iter().zip(learned) {
                values[i] = Some(value);
            }
        }
        Ok(values)
    }

    /// Warms a copy of the trainer up ([`Trainer::warm_up`]) on a thread of its own, telling
    /// the launcher meanwhile that the learner is tuning: a first tune takes seconds on a GPU
    /// and minutes on a software device, past the heartbeat after which a silent role is
    /// killed. Returns at once, leaving the warm-up behind, when the launcher is gone.
    fn warm_up(&mut self, status: &mut Outbox, lifeline: &Lifeline) -> Result<()> {
        let started = Stopwatch::start();
        let scratch = self.trainer.clone();
        let nets = self.config.trained_nets();
        let batch = self.config.learner.batch_size as usize;
        let warm_up = std::thread::spawn(move || scratch.warm_up(nets, batch));
        let mut reported: Option<Instant> = None;
        while !warm_up.is_finished() {
            if lifeline.lost() {
                return Ok(());
            }
            if reported.is_none_or(|at| at.elapsed() >= STATUS_EVERY) {
                status.send(&Message::Status(Status::Tuning {
                    role: Role::Learner,
                }))?;
                reported = Some(Instant::now());
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        match warm_up.join() {
            Ok(warmed) => warmed.context("the learner's warm-up step")?,
            Err(_) => bail!("the learner's warm-up step panicked"),
        }
        self.report.warm_up_s = started.wall_s();
        self.log.log_line(
            LogLevel::Info,
            &format!(
                "warmed up (kernels tuned) in {:.1} s",
                self.report.warm_up_s
            ),
        )?;
        Ok(())
    }

    fn status(&self) -> Message {
        Message::Status(Status::Learner {
            updates: self.updates(),
            weights_version: self.report.weights_version,
            loss: self.report.last_loss,
        })
    }

    /// The last checkpoint, the last report to the launcher, and what this process did
    /// (its CPU time too when it is `own_process`).
    fn finish(mut self, status: &mut Outbox, own_process: bool) -> Result<LearnerReport> {
        self.save_checkpoint()?;
        self.report.updates = self.updates();
        self.report.session_updates = self.updates() - self.updates_before;
        self.report.training_s = self.first_batch.map_or(0.0, |t| t.wall_s());
        self.report.cpu_s = self.first_batch.filter(|_| own_process).map(|t| t.cpu_s());
        status.send(&self.status())?;
        Ok(self.report)
    }
}
