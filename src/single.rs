//! `pushgrasp train-single`: stage-1 training (goal-conditioned grasping) in one process,
//! readable top to bottom: observe, pick a goal, Q maps, the policy, act, reward, label,
//! replay, one learner update, repeat. Every hyper-parameter comes from the config file.
//!
//! A successful grasp's label bootstraps on the next scene's goal grasp Q, so it is learnt
//! one episode later, when that value is known. A grasp that picked a non-goal object is
//! also stored with that object as its goal (goal relabelling). Replay is uniform here; the
//! distributed runtime brings the prioritised buffer.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::Instant;

use actor::{Mode, PolicyConfig, PolicyInput};
use anyhow::{Context, Result, bail};
use clap::Args;
use learner::checkpoint::config_hash;
use learner::label::grasp_label;
use learner::{Checkpoint, LearningConfig, Manifest, Sample, TrainedNet, Trainer};
use qnet::{NetInput, QNetConfig, QNets};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::{Action, Camera, Heightmaps, ObjectId, SimConfig, Tabletop};

/// Goal grasp success is reported over this many most recent attempts (the paper's metric).
const WINDOW: usize = 30;

#[derive(Args)]
pub struct SingleArgs {
    /// The training config (TOML).
    #[arg(long, default_value = "configs/single-stage1.toml")]
    config: PathBuf,
    /// Override the number of episodes.
    #[arg(long)]
    episodes: Option<usize>,
    /// Run directory (default: logs/single-stage1-seed<S>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Measure the random policy instead: grasps drawn uniformly in the goal mask, no learning.
    #[arg(long)]
    random: bool,
    /// After training, this many greedy grasps (epsilon 0; random with --random) on fresh
    /// scenes, none seen in training: the policy's goal grasp success without exploration.
    #[arg(long, default_value_t = 0)]
    eval: usize,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SingleConfig {
    pub stage: u8,
    pub episodes: usize,
    pub seed: u64,
    pub objects: usize,
    pub max_failures_per_scene: usize,
    #[serde(default)]
    pub sim: SimConfig,
    #[serde(default)]
    pub policy: PolicyConfig,
    #[serde(default)]
    pub net: QNetConfig,
    #[serde(default)]
    pub learning: LearningConfig,
    pub replay: ReplayConfig,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayConfig {
    pub capacity: usize,
    /// Samples replayed with each update, besides the newest.
    pub batch: usize,
    /// Learner updates per episode (the first also takes the newest samples).
    #[serde(default = "one")]
    pub updates: usize,
}

fn one() -> usize {
    1
}

impl SingleConfig {
    pub fn load(path: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let config: Self =
            toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        if config.stage != 1 {
            bail!(
                "{}: stage {} is not trained in one process yet (only stage 1)",
                path.display(),
                config.stage
            );
        }
        Ok(config)
    }
}

/// A transition as replay keeps it: the observation (compact), its goal and what happened.
struct Stored {
    obs: Heightmaps,
    goal: ObjectId,
    action: Action,
    label: f32,
}

impl Stored {
    fn sample(&self) -> Sample {
        Sample {
            input: NetInput::encode(&self.obs, self.goal),
            action: self.action,
            label: self.label,
            weight: 1.0,
        }
    }
}

/// A successful grasp waiting for the next scene's value to complete its label.
struct Pending {
    obs: Heightmaps,
    action: Action,
    /// The episode's goal.
    goal: ObjectId,
    /// What the grasp picked (the goal, or another object the grasp is relabelled for).
    picked: ObjectId,
}

/// One row of the learning curve.
#[derive(Serialize)]
struct CurvePoint {
    episode: usize,
    goal_grasped: bool,
    success_last30: f64,
    epsilon: f32,
    predicted_q: f32,
    loss: Option<f32>,
    wall_s: f64,
}

pub fn run(args: &SingleArgs) -> Result<()> {
    let mut config = SingleConfig::load(&args.config)?;
    if let Some(episodes) = args.episodes {
        config.episodes = episodes;
    }
    let out = args.out.clone().unwrap_or_else(|| {
        let kind = if args.random { "random" } else { "stage1" };
        PathBuf::from(format!("logs/single-{kind}-seed{}", config.seed))
    });
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join("config.toml"), toml::to_string(&config)?)?;

    let device = qnet::Backend::selected().device();
    // The nets' initial weights come from the backend's generator.
    device.seed(config.seed);
    let side = config.sim.grid()?.side();
    let mut trainer = Trainer::new(
        QNets::new(&config.net, &device),
        &config.net,
        side,
        &config.learning,
        TrainedNet::Grasp,
        &device,
    );
    let mut nets = trainer.inference_nets();
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut scene_seed = config.seed * 1_000_000;
    let (mut tabletop, _) = Tabletop::random(&config.sim, config.objects, scene_seed)?;
    let camera = Camera::new(tabletop.grid());
    let mut replay: VecDeque<Stored> = VecDeque::with_capacity(config.replay.capacity);
    let mut pending: Option<Pending> = None;
    let mut recent: VecDeque<bool> = VecDeque::with_capacity(WINDOW);
    let mut failures_in_a_row = 0;
    let mut curve = Vec::with_capacity(config.episodes);
    let start = Instant::now();

    for episode in 0..config.episodes {
        // A new scene when this one is cleared or stuck; a pending success then ends the chain.
        let mut obs = camera.render(&tabletop);
        if obs.visible_ids().is_empty() || failures_in_a_row >= config.max_failures_per_scene {
            if let Some(p) = pending.take() {
                finish(
                    p,
                    None,
                    &config.learning,
                    &mut replay,
                    config.replay.capacity,
                );
            }
            scene_seed += 1;
            tabletop = Tabletop::random(&config.sim, config.objects, scene_seed)?.0;
            obs = camera.render(&tabletop);
            failures_in_a_row = 0;
        }
        let visible = obs.visible_ids();
        let Some(&goal) = visible.get(rng.random_range(0..visible.len().max(1))) else {
            continue;
        };

        // Observe and choose.
        let epsilon = if args.random {
            1.0
        } else {
            config.policy.epsilon(episode as u64)
        };
        let decision = choose_grasp(
            &config,
            &nets,
            trainer.geometry(),
            &obs,
            goal,
            epsilon,
            &mut rng,
        )?;

        // The previous success bootstraps on this scene's goal grasp Q.
        let mut fresh = Vec::new();
        if let Some(p) = pending.take() {
            fresh.extend(finish(
                p,
                Some(decision.goal_grasp_q),
                &config.learning,
                &mut replay,
                config.replay.capacity,
            ));
        }

        // Act and score.
        let outcome = tabletop.act(&decision.action, &obs)?;
        let reward = actor::grasp_reward(outcome.grasped, goal);
        let goal_grasped = reward > 0.0;
        failures_in_a_row = if outcome.grasped.is_some() {
            0
        } else {
            failures_in_a_row + 1
        };
        match outcome.grasped {
            // The goal and, relabelled, whatever else was picked: labels wait for the next scene.
            Some(picked) => {
                pending = Some(Pending {
                    obs,
                    action: decision.action,
                    goal,
                    picked,
                });
            }
            None => {
                let stored = Stored {
                    obs,
                    goal,
                    action: decision.action,
                    label: grasp_label(reward, false, None, config.learning.gamma),
                };
                fresh.push(remember(&mut replay, stored, config.replay.capacity));
            }
        }

        // Learn: the newest samples and a few replayed ones.
        let mut loss = None;
        if !args.random && !replay.is_empty() {
            for _ in 0..config.replay.updates {
                let mut batch = std::mem::take(&mut fresh);
                for _ in 0..config.replay.batch.min(replay.len()) {
                    batch.push(replay[rng.random_range(0..replay.len())].sample());
                }
                loss = Some(trainer.train_step(&batch)?.loss);
            }
            nets = trainer.inference_nets();
        }

        if recent.len() == WINDOW {
            recent.pop_front();
        }
        recent.push_back(goal_grasped);
        let success = recent.iter().filter(|&&s| s).count() as f64 / recent.len() as f64;
        curve.push(CurvePoint {
            episode: episode + 1,
            goal_grasped,
            success_last30: success,
            epsilon,
            predicted_q: decision.predicted_q,
            loss,
            wall_s: start.elapsed().as_secs_f64(),
        });
        if (episode + 1) % 10 == 0 || episode + 1 == config.episodes {
            println!(
                "episode {:4}  goal grasp success (last {WINDOW}) {:5.1}%  epsilon {:.3}  Q {:6.3}  loss {}  {:6.1} s",
                episode + 1,
                100.0 * success,
                epsilon,
                decision.predicted_q,
                loss.map_or("-".into(), |l| format!("{l:.4}")),
                start.elapsed().as_secs_f64()
            );
        }
    }

    write_curve(&out.join("curve.csv"), &curve)?;
    if !args.random {
        let checkpoint = Checkpoint::at(out.join("checkpoint"));
        let manifest = Manifest {
            stage: config.stage,
            updates: trainer.updates(),
            side,
            config_hash: config_hash(&config.net),
        };
        checkpoint.save(&manifest, &trainer.inference_nets().to_bytes()?)?;
    }
    let first = curve.iter().take(WINDOW).filter(|p| p.goal_grasped).count();
    println!(
        "done: {} episodes in {:.1} s; goal grasp success first {WINDOW}: {:.1}%, last {WINDOW}: {:.1}%; curve in {}",
        curve.len(),
        start.elapsed().as_secs_f64(),
        100.0 * first as f64 / WINDOW.min(curve.len()).max(1) as f64,
        100.0 * curve.last().map_or(0.0, |p| p.success_last30),
        out.join("curve.csv").display()
    );
    if args.eval > 0 {
        let epsilon = if args.random { 1.0 } else { 0.0 };
        let (successes, attempts) =
            evaluate(&config, &nets, trainer.geometry(), args.eval, epsilon)?;
        println!(
            "evaluation: goal grasp success {:.1}% ({successes} of {attempts} grasps, epsilon {epsilon})",
            100.0 * successes as f64 / attempts as f64
        );
    }
    Ok(())
}

/// The grasp-only policy's decision on an observation: Q maps for every rotation, then the
/// epsilon-greedy choice inside the goal mask.
fn choose_grasp(
    config: &SingleConfig,
    nets: &QNets,
    geometry: &qnet::Geometry,
    obs: &Heightmaps,
    goal: ObjectId,
    epsilon: f32,
    rng: &mut ChaCha8Rng,
) -> Result<actor::Decision> {
    let input = NetInput::encode(obs, goal);
    let grasp = nets.all_rotations(sim::Primitive::Grasp, &input, geometry)?;
    let policy_input = PolicyInput {
        obs,
        goal,
        grasp: &grasp,
        push: None,
        pushes_so_far: 0,
    };
    Ok(actor::choose(
        &config.policy,
        Mode::GraspOnly,
        &policy_input,
        epsilon,
        rng,
    )?)
}

/// Grasps with the given nets on scenes none of training saw (seeded apart from them), a few
/// goals per scene: (goal grasps, attempts).
fn evaluate(
    config: &SingleConfig,
    nets: &QNets,
    geometry: &qnet::Geometry,
    attempts: usize,
    epsilon: f32,
) -> Result<(usize, usize)> {
    const GOALS_PER_SCENE: usize = 3;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed ^ 0xe7a1);
    let (mut successes, mut done) = (0, 0);
    let mut scene_seed = u64::MAX / 2 + config.seed * 1_000_000;
    while done < attempts {
        scene_seed += 1;
        let (mut tabletop, _) = Tabletop::random(&config.sim, config.objects, scene_seed)?;
        let camera = Camera::new(tabletop.grid());
        for _ in 0..GOALS_PER_SCENE.min(attempts - done) {
            let obs = camera.render(&tabletop);
            let visible = obs.visible_ids();
            let Some(&goal) = visible.get(rng.random_range(0..visible.len().max(1))) else {
                break;
            };
            let decision = choose_grasp(config, nets, geometry, &obs, goal, epsilon, &mut rng)?;
            let outcome = tabletop.act(&decision.action, &obs)?;
            successes += usize::from(outcome.grasped == Some(goal));
            done += 1;
        }
    }
    Ok((successes, done))
}

/// Completes a pending success's labels with the next value and stores them; returns them
/// as samples. A non-goal pick is stored twice: for the episode's goal, which earned nothing,
/// and relabelled for the object picked, which it grasped.
fn finish(
    pending: Pending,
    next_value: Option<f32>,
    learning: &LearningConfig,
    replay: &mut VecDeque<Stored>,
    capacity: usize,
) -> Vec<Sample> {
    let success = grasp_label(1.0, true, next_value, learning.gamma);
    let mut labelled = vec![(pending.picked, success)];
    if pending.picked != pending.goal {
        labelled.insert(
            0,
            (pending.goal, grasp_label(0.0, false, None, learning.gamma)),
        );
    }
    labelled
        .into_iter()
        .map(|(goal, label)| {
            let stored = Stored {
                obs: pending.obs.clone(),
                goal,
                action: pending.action,
                label,
            };
            remember(replay, stored, capacity)
        })
        .collect()
}

/// Adds a transition to replay, dropping the oldest when full; returns it as a sample.
fn remember(replay: &mut VecDeque<Stored>, stored: Stored, capacity: usize) -> Sample {
    let sample = stored.sample();
    if replay.len() == capacity {
        replay.pop_front();
    }
    replay.push_back(stored);
    sample
}

fn write_curve(path: &Path, curve: &[CurvePoint]) -> Result<()> {
    let mut text =
        String::from("episode,goal_grasped,success_last30,epsilon,predicted_q,loss,wall_s\n");
    for p in curve {
        text.push_str(&format!(
            "{},{},{:.4},{:.4},{:.4},{},{:.3}\n",
            p.episode,
            u8::from(p.goal_grasped),
            p.success_last30,
            p.epsilon,
            p.predicted_q,
            p.loss.map_or(String::new(), |l| format!("{l:.5}")),
            p.wall_s
        ));
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
