//! Test runs: on each case, `runs` runs of the greedy policy (no exploration, no learning
//! unless asked, BatchNorm on its running statistics because the nets act on the plain
//! backend), in parallel over the cores, each judged by [`crate::metrics`].
//!
//! The simulator is deterministic, so the runs of a designed arrangement would all be the
//! same run: each run moves every object by a small seeded jitter (1 mm, 1 degree by default;
//! [`Arrangement::jittered`]) before the scene settles, standing in for the run-to-run noise
//! of the paper's simulator.
//!
//! Goal-agnostic runs ([`EvalConfig::goal_agnostic`]) give the agent every object as its goal
//! ([`sim::ANY_OBJECT`]) and go on until the table is clear.
//!
//! The authors' test protocol is here too, as options: learning during the test
//! ([`EvalConfig::learning`], [`crate::test_learning`]), and their rule, which tests the
//! goal's border on designed cases only ([`EvalConfig::random_scene_rule`]).

use learner::LearnerError;
use policy::Rule;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sim::measure::{occupancy_ratio, scene_changed};
use sim::workspace::inside_by;
use sim::{ANY_OBJECT, Arrangement, Camera, ObjectId, Primitive, SimConfig, SimError, Tabletop};

use crate::agent::{Agent, AgentError, Situation};
use crate::metrics::{ActionAt, ActionRecord, CaseMetrics, RunRecord};
use crate::test_learning::{RunLearner, TestLearning};

/// How the test runs are made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalConfig {
    pub sim: SimConfig,
    /// Runs per case (the paper: 30).
    pub runs: usize,
    /// Every run's scene and goal derive from this seed, the case and the run index.
    pub seed: u64,
    /// Largest shift of each arranged object in x and y (metres) ...
    pub jitter_m: f32,
    /// ... and about the vertical (radians).
    pub jitter_rad: f32,
    /// A run still undecided after this many actions per object it must pick counts as
    /// incomplete (a guard: the policy's five-push limit and the ten failures already bound
    /// a run).
    pub max_actions: usize,
    /// Clear the table instead of picking the case's goal: every object is the goal.
    pub goal_agnostic: bool,
    /// Learn during each run, from the checkpoint's nets at its start (the authors' code);
    /// `None`: the nets stay as they are (the paper's test).
    pub learning: Option<TestLearning>,
    /// The rule random scenes are tested under where it is not the agent's own: the
    /// authors' test rule leaves its border test out there.
    pub random_scene_rule: Option<Rule>,
    /// Remember the grasps that picked nothing since the last push and make none of them
    /// again ([`policy::PolicyInput::failed_grasps`]): frozen nets in a scene a failed grasp
    /// left as it was choose the same grasp again.
    pub avoid_failed_grasps: bool,
    /// After a push that moved nothing ([`sim::measure::scene_changed`]), grasp, as when the
    /// push budget is spent: frozen nets in a scene left as it was choose the same push
    /// again, until the budget is spent, and then grasp in that same scene.
    pub grasp_after_idle_push: bool,
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self {
            sim: SimConfig::default(),
            runs: 30,
            seed: 0,
            jitter_m: 0.001,
            jitter_rad: 1f32.to_radians(),
            max_actions: 100,
            goal_agnostic: false,
            learning: None,
            random_scene_rule: None,
            avoid_failed_grasps: false,
            grasp_after_idle_push: false,
        }
    }
}

/// A test case's scene.
#[derive(Clone, Debug)]
pub enum Scene {
    /// A designed arrangement with its goal.
    Arrangement(Arrangement),
    /// `objects` dropped at random, a visible one drawn as the goal.
    Random { objects: usize },
}

/// Why an evaluation stopped.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("case {case}: {source}")]
    Sim {
        case: String,
        #[source]
        source: SimError,
    },
    #[error("case {case}: {source}")]
    Agent {
        case: String,
        #[source]
        source: AgentError,
    },
    #[error("case {case}: the arrangement names no goal object")]
    NoGoal { case: String },
    #[error("case {case}: the scene has no visible object to take as the goal")]
    EmptyScene { case: String },
    #[error("case {case}: learning during the test: {source}")]
    Learner {
        case: String,
        #[source]
        source: LearnerError,
    },
    #[error("learning during the test needs a goal: a goal-agnostic test has no labels")]
    LearningWithoutGoal,
}

/// A case's runs and figures.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CaseReport {
    pub name: String,
    pub metrics: CaseMetrics,
    pub runs: Vec<RunRecord>,
}

/// Runs every case `config.runs` times with agents from `make_agent` (one per worker thread)
/// and judges them. The result depends on the seed, not on the number of threads.
pub fn evaluate(
    make_agent: impl Fn() -> Agent + Sync,
    cases: &[(String, Scene)],
    config: &EvalConfig,
) -> Result<Vec<CaseReport>, EvalError> {
    if config.goal_agnostic && config.learning.is_some() {
        return Err(EvalError::LearningWithoutGoal);
    }
    let jobs: Vec<(usize, usize)> = (0..cases.len())
        .flat_map(|c| (0..config.runs).map(move |r| (c, r)))
        .collect();
    let records: Vec<RunRecord> = jobs
        .par_iter()
        .map_init(&make_agent, |agent, &(c, r)| {
            let (name, scene) = &cases[c];
            test_run(agent, scene, config, run_seed(config.seed, c, r)).map_err(|e| e.in_case(name))
        })
        .collect::<Result<_, _>>()?;
    let mut records = records.into_iter();
    Ok(cases
        .iter()
        .map(|(name, _)| {
            let runs: Vec<RunRecord> = records.by_ref().take(config.runs).collect();
            let outcomes: Vec<_> = runs.iter().map(RunRecord::outcome).collect();
            CaseReport {
                name: name.clone(),
                metrics: CaseMetrics::of(&outcomes),
                runs,
            }
        })
        .collect())
}

fn run_seed(seed: u64, case: usize, run: usize) -> u64 {
    seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ ((case as u64) << 32) ^ run as u64
}

/// What went wrong in one run, before the case is named.
enum RunError {
    Sim(SimError),
    Agent(AgentError),
    NoGoal,
    EmptyScene,
    Learner(LearnerError),
}

impl RunError {
    fn in_case(self, case: &str) -> EvalError {
        let case = case.to_string();
        match self {
            RunError::Sim(source) => EvalError::Sim { case, source },
            RunError::Agent(source) => EvalError::Agent { case, source },
            RunError::NoGoal => EvalError::NoGoal { case },
            RunError::EmptyScene => EvalError::EmptyScene { case },
            RunError::Learner(source) => EvalError::Learner { case, source },
        }
    }
}

/// One test run: the scene, then greedy actions until the run is decided, the goal has left
/// the table (the table is clear, for a goal-agnostic run), or the action guard is reached.
/// The agent is the run's own copy: a run that learns starts from the checkpoint's nets.
fn test_run(
    agent: &Agent,
    scene: &Scene,
    config: &EvalConfig,
    seed: u64,
) -> Result<RunRecord, RunError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut agent = agent.clone();
    if let (Scene::Random { .. }, Some(rule)) = (scene, config.random_scene_rule) {
        agent.policy.rule = rule;
    }
    let mut learner = config
        .learning
        .as_ref()
        .map(|learning| RunLearner::start(learning, agent.nets(), &agent.geometry));
    let (mut tabletop, goal) = build(scene, config, &mut rng)?;
    let camera = Camera::new(tabletop.grid());
    let on_table = |tabletop: &Tabletop| match goal {
        ANY_OBJECT => tabletop.objects().count(),
        goal => usize::from(tabletop.object(goal).is_some()),
    };
    let max_actions = config.max_actions * on_table(&tabletop);
    let mut record = RunRecord {
        goal,
        actions: Vec::new(),
        objects_left: tabletop.objects().count(),
        goal_lost: false,
        updates: 0,
    };
    let mut pushes = 0;
    // The grasps that picked nothing since the last push.
    let mut failed_grasps = Vec::new();
    let mut before_push = None;
    while record.actions.len() < max_actions && !record.outcome().decided {
        let obs = camera.render(&tabletop);
        let landing_view = (agent.policy)
            .landing_view(tabletop.grid())
            .map(|grid| Camera::new(grid).render(&tabletop));
        if let Some(before) = before_push.take()
            && !scene_changed(&before, &obs)
        {
            pushes = pushes.max(agent.policy.max_pushes);
        }
        let situation = Situation {
            obs: &obs,
            landing_view: landing_view.as_ref(),
            goal,
            pushes_so_far: pushes,
            failed_grasps: if config.avoid_failed_grasps {
                &failed_grasps
            } else {
                &[]
            },
            grasp_failed_since_push: !failed_grasps.is_empty(),
            epsilon: 0.0,
            rng: &mut rng,
        };
        let choice = agent.decide(situation).map_err(RunError::Agent)?;
        let decision = choice.decision;
        if let Some(learner) = &mut learner
            && let Some(nets) = learner.learn(&obs, &decision).map_err(RunError::Learner)?
        {
            agent
                .act_with(nets)
                .map_err(|e| RunError::Agent(e.into()))?;
        }
        let action = decision.action;
        let goal_inside_edge = tabletop.object(goal).map(|o| {
            let centre = o.pose.translation;
            inside_by(centre.x, centre.y)
        });
        let outcome = tabletop.act(&action, &obs).map_err(RunError::Sim)?;
        if let Some(learner) = &mut learner {
            learner.executed(&obs, goal, decision, outcome.grasped);
        }
        match action.primitive {
            Primitive::Push => {
                pushes += 1;
                failed_grasps.clear();
                if config.grasp_after_idle_push {
                    before_push = Some(obs.clone());
                }
            }
            Primitive::Grasp => {
                pushes = 0;
                if outcome.grasped.is_none() {
                    failed_grasps.push(action);
                }
            }
        }
        record.actions.push(ActionRecord {
            primitive: action.primitive,
            at: Some(ActionAt::from(&action)),
            grasped: outcome.grasped,
            goal_grasp_q: decision.goal_grasp_q,
            goal_border_occupancy: Some(occupancy_ratio(&obs, goal)),
            goal_inside_edge,
        });
        record.objects_left = tabletop.objects().count();
        record.goal_lost =
            goal != ANY_OBJECT && outcome.grasped != Some(goal) && tabletop.object(goal).is_none();
    }
    record.updates = learner.as_ref().map_or(0, RunLearner::updates);
    Ok(record)
}

/// The run's tabletop, settled, and its goal.
fn build(
    scene: &Scene,
    config: &EvalConfig,
    rng: &mut ChaCha8Rng,
) -> Result<(Tabletop, ObjectId), RunError> {
    match scene {
        Scene::Arrangement(arrangement) => {
            let goal = match arrangement.goal {
                _ if config.goal_agnostic => ANY_OBJECT,
                goal => goal.ok_or(RunError::NoGoal)?,
            };
            let jittered = arrangement.jittered(config.jitter_m, config.jitter_rad, rng);
            let mut tabletop =
                Tabletop::from_arrangement(&config.sim, &jittered).map_err(RunError::Sim)?;
            tabletop.settle();
            Ok((tabletop, goal))
        }
        Scene::Random { objects } => {
            let (tabletop, _) =
                Tabletop::random(&config.sim, *objects, rng.random()).map_err(RunError::Sim)?;
            let visible = Camera::new(tabletop.grid()).render(&tabletop).visible_ids();
            let goal = *visible
                .get(rng.random_range(0..visible.len().max(1)))
                .ok_or(RunError::EmptyScene)?;
            Ok((
                tabletop,
                if config.goal_agnostic {
                    ANY_OBJECT
                } else {
                    goal
                },
            ))
        }
    }
}
