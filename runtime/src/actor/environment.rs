//! One environment of an actor process and its episode rules: which goal an episode takes,
//! when a scene is dropped anew, and which waiting steps an action completes.

use agent::{Choice, Situation};
use anyhow::Result;
use experience::Transition;
use mcaplog::RunLog;
use policy::{Decision, QMaps, trial_grasps};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sim::measure::{detect_change, most_crowded};
use sim::{Camera, Heightmaps, ObjectId, Primitive, Tabletop, workspace};
use wire::Origin;

use super::id::ActorId;
use super::pictures::log_pictures;
use super::ship::{Stream, Unlabelled};
use rundir::ActorReport;
use rundir::config::RunConfig;

/// A step completed by the decision after it (`None`: its scene ended, or its push lost the
/// goal), to be shipped.
pub(super) type Completed = (Unlabelled, Option<Decision>);

/// One environment of an actor process: the scene it plays on, its exploration, its
/// episode under way, the step still waiting for the next decision, and its stream.
pub(super) struct Environment<'a> {
    config: &'a RunConfig,
    pub(super) id: ActorId,
    log: &'a RunLog,
    rng: ChaCha8Rng,
    scene_seed: u64,
    tabletop: Tabletop,
    camera: Camera,
    episode: Option<Episode>,
    /// The scene on the policy's landing view grid, rendered for each decision.
    landing_view: Option<Heightmaps>,
    unlabelled: Option<Unlabelled>,
    /// Grasps in a row that held nothing: a scene stuck for too long is replaced.
    failures_in_a_row: usize,
    /// The last episode's goal, kept for the scene's next episode under `goal_per_scene`.
    scene_goal: Option<ObjectId>,
    pub(super) stream: Stream,
    pub(super) report: ActorReport,
}

/// An episode under way: what the environment sees now, the goal, and its actions so far.
struct Episode {
    obs: Heightmaps,
    goal: ObjectId,
    step: u32,
}

impl<'a> Environment<'a> {
    pub(super) fn new(config: &'a RunConfig, id: ActorId, log: &'a RunLog) -> Result<Self> {
        let seed = id.seed(config.seed);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let tabletop = Self::new_scene(config, seed, &mut rng)?;
        Ok(Self {
            config,
            id,
            log,
            rng,
            scene_seed: seed,
            camera: Camera::new(tabletop.grid()),
            tabletop,
            episode: None,
            landing_view: None,
            unlabelled: None,
            failures_in_a_row: 0,
            scene_goal: None,
            stream: Stream::new(Origin {
                actor: id.index,
                incarnation: id.incarnation,
                seq: 0,
            }),
            report: ActorReport {
                actor: id.index,
                incarnation: id.incarnation,
                ..ActorReport::default()
            },
        })
    }

    fn new_scene(config: &RunConfig, seed: u64, rng: &mut ChaCha8Rng) -> Result<Tabletop> {
        let rows = config.rows.draw(rng);
        Ok(Tabletop::random_with_rows(&config.sim, config.objects, rows, seed)?.0)
    }

    /// Between episodes, starts one: on a new scene when this one has no goal left to take
    /// ([`Self::goal_candidates`]) or is stuck, for a candidate at random, or the most
    /// crowded one in the config's share of episodes (none while no candidate is seen: it
    /// tries again next time). Under `goal_per_scene` the scene's goal is taken again while
    /// it is seen, and its leaving the view ends the scene. A new scene dropped for an empty
    /// or stuck one ends the chain of the step waiting: returned, to ship as it is.
    pub(super) fn episode_start(&mut self) -> Result<Option<Unlabelled>> {
        if self.episode.is_some() {
            return Ok(None);
        }
        let mut chain_end = None;
        let mut obs = self.camera.render(&self.tabletop);
        let mut candidates = self.goal_candidates(&obs);
        let kept = self
            .scene_goal
            .filter(|goal| self.config.goal_per_scene && candidates.contains(goal));
        let goal_left = self.config.goal_per_scene && self.scene_goal.is_some() && kept.is_none();
        let renew = candidates.is_empty()
            || goal_left
            || self.failures_in_a_row >= self.config.max_failures_per_scene;
        if renew {
            // The goal's leaving is no end of the chain: the step waiting bootstraps on the
            // fresh drop's first decision, as the original's label reads the next image,
            // which keeps the grasp Q on the scale Q* is set for. An empty or stuck scene's
            // last step ships as it is.
            if !goal_left {
                chain_end = self.unlabelled.take();
            }
            self.scene_seed = self.scene_seed.wrapping_add(1);
            self.tabletop = Self::new_scene(self.config, self.scene_seed, &mut self.rng)?;
            obs = self.camera.render(&self.tabletop);
            candidates = self.goal_candidates(&obs);
            self.failures_in_a_row = 0;
        }
        let goal = match kept {
            Some(goal) if !renew => Some(goal),
            _ => self.draw_goal(&obs, &candidates),
        };
        self.scene_goal = goal;
        if let Some(goal) = goal {
            self.episode = Some(Episode { obs, goal, step: 0 });
        }
        Ok(chain_end)
    }

    /// A goal among `candidates`: the most crowded in the config's share of draws, else one
    /// at random.
    fn draw_goal(&mut self, obs: &Heightmaps, candidates: &[ObjectId]) -> Option<ObjectId> {
        // No draw at a share of 0: the episodes' goals stay those of the seed without it.
        let share = self.config.crowded_goals;
        if share > 0.0 && self.rng.random::<f64>() < share {
            most_crowded(obs, candidates)
        } else {
            candidates
                .get(self.rng.random_range(0..candidates.len().max(1)))
                .copied()
        }
    }

    /// The objects an episode may take as its goal: those seen, under `goals_over_workspace`
    /// only those whose centre lies over the workspace.
    fn goal_candidates(&self, obs: &Heightmaps) -> Vec<ObjectId> {
        let mut seen = obs.visible_ids();
        if self.config.goals_over_workspace {
            seen.retain(|&id| {
                self.tabletop.object(id).is_some_and(|o| {
                    let centre = o.pose.translation;
                    workspace::contains(centre.x, centre.y)
                })
            });
        }
        seen
    }

    /// Whether an episode is under way (between its start and its grasp).
    pub(super) fn in_episode(&self) -> bool {
        self.episode.is_some()
    }

    /// What the agent decides on in this environment, while an episode is under way.
    pub(super) fn situation(&mut self) -> Option<Situation<'_>> {
        let episode = self.episode.as_ref()?;
        self.landing_view = (self.config.policy)
            .landing_view(self.tabletop.grid())
            .map(|grid| Camera::new(grid).render(&self.tabletop));
        Some(Situation {
            obs: &episode.obs,
            landing_view: self.landing_view.as_ref(),
            goal: episode.goal,
            pushes_so_far: episode.step as usize,
            failed_grasps: &[],
            // A grasp ends the episode.
            grasp_failed_since_push: false,
            epsilon: self.config.epsilon(self.id.index, self.report.actions),
            rng: &mut self.rng,
        })
    }

    /// Acts on `choice` (made with weights `weights_version`): a push goes on with the
    /// episode, a grasp ends it. Returns the steps the choice completed.
    pub(super) fn act(&mut self, choice: Choice, weights_version: u64) -> Result<Vec<Completed>> {
        let Episode { obs, goal, step } = self.episode.take().expect("acting in an episode");
        let pictures_ns = self.pictures(&obs, &choice)?;
        let Choice {
            decision, grasp, ..
        } = choice;
        let mut completed: Vec<Completed> = self
            .unlabelled
            .take()
            .map(|p| (p, Some(decision)))
            .into_iter()
            .collect();
        if decision.action.primitive == Primitive::Grasp && self.config.grasp_trials > 0 {
            completed.extend(self.trials(&obs, goal, &grasp, &decision, weights_version)?);
        }
        let outcome = self.tabletop.act(&decision.action, &obs)?;
        self.report.actions += 1;
        let transition = Transition {
            episode: self.id.episode(self.report.episodes),
            step,
            goal,
            obs,
            action: decision.action,
            reward: 0.0,
            grasped: outcome.grasped,
            next_value: None,
            next: None,
        };
        if decision.action.primitive == Primitive::Push {
            let obs = self.camera.render(&self.tabletop);
            let push = Unlabelled {
                push_changed: Some(detect_change(&transition.obs, &obs, goal)),
                transition,
                decision,
                ends: None,
                scene_seed: self.scene_seed,
                pictures_ns,
                weights_version,
            };
            if self.config.goal_lost_ends_episode && self.tabletop.object(goal).is_none() {
                // Nothing after this push can pick the goal: it is the episode's last step.
                self.report.episodes += 1;
                completed.push((push.ending_episode(), None));
                return Ok(completed);
            }
            self.unlabelled = Some(push);
            self.episode = Some(Episode {
                obs,
                goal,
                step: step + 1,
            });
            return Ok(completed);
        }
        self.failures_in_a_row = if outcome.grasped.is_some() {
            0
        } else {
            self.failures_in_a_row + 1
        };
        let grasp = Unlabelled::grasp(
            transition,
            decision,
            false,
            self.scene_seed,
            pictures_ns,
            weights_version,
        );
        self.report.episodes += 1;
        self.report.goal_grasps += u64::from(grasp.transition.reward > 0.0);
        self.unlabelled = Some(grasp);
        Ok(completed)
    }

    /// The pictures of this step, every `image_every` episodes: when they were logged.
    fn pictures(&self, obs: &Heightmaps, choice: &Choice) -> Result<Option<u64>> {
        let every = self.config.logging.image_every;
        (every > 0 && self.report.episodes.is_multiple_of(every))
            .then(|| {
                log_pictures(
                    self.log,
                    &self.tabletop,
                    obs,
                    &choice.grasp,
                    choice.push.as_ref(),
                )
            })
            .transpose()
    }

    /// Grasps tried on copies of the scene beside the executed one (`grasp_trials`), each
    /// an episode of its own, completed at once.
    fn trials(
        &mut self,
        obs: &Heightmaps,
        goal: ObjectId,
        grasp: &QMaps,
        decision: &Decision,
        weights_version: u64,
    ) -> Result<Vec<Completed>> {
        let trials = trial_grasps(
            obs,
            goal,
            grasp,
            decision,
            self.config.grasp_trials,
            &self.config.policy,
            &mut self.rng,
        )?;
        let mut completed = Vec::with_capacity(trials.len());
        for trial in trials {
            let outcome = self.tabletop.replica().act(&trial.action, obs)?;
            let transition = Transition {
                episode: self.id.trial(self.report.trials),
                step: 0,
                goal,
                obs: obs.clone(),
                action: trial.action,
                reward: 0.0,
                grasped: outcome.grasped,
                next_value: None,
                next: None,
            };
            self.report.trials += 1;
            let unlabelled = Unlabelled::grasp(
                transition,
                trial,
                true,
                self.scene_seed,
                None,
                weights_version,
            );
            // A successful trial bootstraps on the executed grasp's view of this scene (its
            // goal grasp Q), standing in for the scene it would leave.
            completed.push((unlabelled, Some(*decision)));
        }
        Ok(completed)
    }
}

#[cfg(test)]
mod tests;
