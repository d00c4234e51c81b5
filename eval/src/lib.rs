//! `pushgrasp eval`: a checkpoint tested the paper's way: `--runs` greedy runs per case on
//! the designed arrangements and/or random scenes, scored with completion, goal grasp success
//! and motion number, per case and averaged over the arrangements (the paper's "challenging"
//! column; random scenes are their own column), as a table like the paper's or as JSON.
//! `--goal-agnostic` clears the table instead (the paper's goal-agnostic test).
//!
//! The authors' test protocol, where it is not the paper's, is two options: `--learn` (one
//! update per executed action, the nets restored at each run's start) and `--authors-rule`
//! (Q* 1.5, and on designed cases a push while the goal's border is crowded). Their metric
//! (any object picked counts) is always printed beside ours. `--why` says how the runs
//! failed ([`agent::failures`]).

mod table;

use std::path::{Path, PathBuf};

use agent::evaluate::CaseReport;
use agent::failures::FailureReport;
use agent::{Agent, CaseMetrics, EvalConfig, RunOutcome, RunRecord, Scene, TestLearning};
use anyhow::{Context, Result, bail};
use clap::Args;
use learner::checkpoint::config_hash;
use policy::Rule;
use serde::Serialize;

use rundir::backend::{self, Backend};
use rundir::config::RunConfig;
use rundir::settings::{merge, parse_setting, read_table};
use rundir::{load_agent, named_arrangements};

use table::{CaseRow, EvalReport, print_table, print_why};

#[derive(Args)]
pub struct EvalArgs {
    /// A checkpoint directory (a run's `checkpoint/`).
    #[arg(long)]
    checkpoint: PathBuf,
    /// More checkpoints to act together with --checkpoint's nets: at every decision the Q
    /// maps of all of them are averaged (an ensemble). Each is read with its own run's
    /// config, which must give the same nets and heightmap size.
    #[arg(long, num_args = 1.., value_name = "CHECKPOINT")]
    ensemble: Vec<PathBuf>,
    /// The config the checkpoint was trained with (default: `config.toml` in the
    /// checkpoint's parent, the run directory); it gives the nets' shape, the simulator and
    /// the policy (Q*, pushes per grasp).
    #[arg(long)]
    config: Option<PathBuf>,
    /// A setting that replaces the config's, for this evaluation: a dotted key and a TOML
    /// value, e.g. `--set policy.q_star=1.5` (an ensemble's averaged maps peak lower than
    /// one net's, so it may want a lower Q*) or `--set policy.grasp_margin=0.02`.
    /// Repeatable; it changes --checkpoint's config, whose policy acts.
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = parse_setting)]
    set: Vec<toml::Table>,
    /// A TOML file of settings that replace the config's, as --set does (any --set goes on
    /// top): `configs/test-time.toml` holds the test-time settings Table 1 is measured with.
    #[arg(long, value_name = "FILE")]
    settings: Option<PathBuf>,
    /// The backend the nets act on, `cpu` or `wgpu` (default: the config's
    /// `backend.actors`); for --ensemble's nets too.
    #[arg(long)]
    backend: Option<Backend>,
    /// Arrangement files (our TOML, with a goal) or directories of them.
    #[arg(long, num_args = 1..)]
    arrangements: Vec<PathBuf>,
    /// One more case: random scenes of this many objects (the paper: 30).
    #[arg(long)]
    random: Option<usize>,
    /// Runs per case (the paper: 30).
    #[arg(long, default_value_t = 30)]
    runs: usize,
    /// Scenes, jitter and goals derive from this seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Test the grasp net alone (the grasping-only baseline): no pushes.
    #[arg(long)]
    grasp_only: bool,
    /// Goal-agnostic: every object is the goal (all objects masked) and a run clears the
    /// table; grasp success counts every object picked.
    #[arg(long)]
    goal_agnostic: bool,
    /// Learn during the test, as the authors' code does: each executed action's label (the
    /// checkpoint's stage's training label) and one update of its net, from a fresh Adam at
    /// the stage's learning rate; the checkpoint's nets are restored at each run's start.
    #[arg(long, conflicts_with_all = ["goal_agnostic", "ensemble"])]
    learn: bool,
    /// The authors' test-time rule instead of the config's: Q* 1.5, and on the designed
    /// arrangements also a push while the goal's border ring is more than 0.3 occupied
    /// (`policy.crowded_border`); random scenes by the Q* alone.
    #[arg(long, conflicts_with = "grasp_only")]
    authors_rule: bool,
    /// Make no grasp again that picked nothing since the last push, nor one within 1 cm of
    /// it at its rotation or the next either side, nor those turned half round: frozen nets
    /// in a scene a failed grasp left as it was choose the same grasp again.
    #[arg(long)]
    avoid_failed_grasps: bool,
    /// After a push that moved nothing, grasp, as when the push budget is spent: frozen nets
    /// in a scene left as it was choose the same push again until the budget is spent.
    #[arg(long)]
    grasp_after_idle_push: bool,
    /// Also say why runs failed: how incomplete runs ended, what the grasps picked, what the
    /// pushes did for the goal, and how often grasps at each goal grasp Q picked the goal.
    #[arg(long)]
    why: bool,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Also write every run to this file, one JSON object per line: its case, index, goal,
    /// outcome and actions (primitive, where it was made (rotation, row, column), object
    /// grasped, and when it was chosen the goal's grasp Q, its border's occupancy and how
    /// far inside the workspace's edge it lay).
    #[arg(long, value_name = "FILE")]
    runs_json: Option<PathBuf>,
}

/// The authors' test-time Q* (`main.py`: push below a goal grasp Q of 1.5).
const AUTHORS_Q_STAR: f32 = 1.5;

/// One line of `--runs-json`.
#[derive(Serialize)]
struct RunLine<'a> {
    case: &'a str,
    run: usize,
    outcome: RunOutcome,
    #[serde(flatten)]
    record: &'a RunRecord,
}

pub fn run(args: &EvalArgs) -> Result<()> {
    let mode = if args.grasp_only {
        policy::Mode::GraspOnly
    } else {
        policy::Mode::PushGrasp
    };
    let (config, agent, updates) = load_nets(args, mode)?;
    let cases = cases(args)?;
    let learning = args.learn.then(|| TestLearning {
        net: config.net.clone(),
        learning: config.learning.clone(),
        trained: config.trained_nets().to_vec(),
        push_reward: config.push_reward,
    });
    let eval = EvalConfig {
        sim: config.sim.clone(),
        runs: args.runs,
        seed: args.seed,
        goal_agnostic: args.goal_agnostic,
        learning,
        random_scene_rule: args.authors_rule.then_some(Rule::Threshold),
        avoid_failed_grasps: args.avoid_failed_grasps,
        grasp_after_idle_push: args.grasp_after_idle_push,
        ..EvalConfig::default()
    };
    let reports = agent::evaluate(|| agent.clone(), &cases, &eval)?;
    if let Some(path) = &args.runs_json {
        write_runs(path, &reports)?;
    }
    let arranged: Vec<&CaseReport> = reports
        .iter()
        .zip(&cases)
        .filter(|(_, (_, scene))| matches!(scene, Scene::Arrangement(_)))
        .map(|(r, _)| r)
        .collect();
    let average = (!arranged.is_empty())
        .then(|| CaseMetrics::average(&arranged.iter().map(|r| r.metrics).collect::<Vec<_>>()));
    let why = args.why && !args.goal_agnostic;
    let arrangements_why = (why && !arranged.is_empty())
        .then(|| FailureReport::of(arranged.iter().flat_map(|r| &r.runs)));
    let rows: Vec<CaseRow> = reports
        .into_iter()
        .map(|r| CaseRow {
            why: why.then(|| FailureReport::of(&r.runs)),
            case: r.name,
            metrics: r.metrics,
        })
        .collect();
    let report = EvalReport {
        checkpoint: args.checkpoint.display().to_string(),
        ensemble: args
            .ensemble
            .iter()
            .map(|c| c.display().to_string())
            .collect(),
        updates,
        runs_per_case: args.runs,
        seed: args.seed,
        mode,
        policy: agent.policy.clone(),
        avoid_failed_grasps: eval.avoid_failed_grasps,
        grasp_after_idle_push: eval.grasp_after_idle_push,
        guarded_push_descent: config.sim.guarded_push_descent,
        goal_agnostic: args.goal_agnostic,
        learning: eval.learning,
        random_scene_rule: eval.random_scene_rule,
        cases: rows,
        average,
        arrangements_why,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_table(&report);
        print_why(&report);
    }
    Ok(())
}

/// The tested nets (`--checkpoint`, and each `--ensemble` member as one more vote) and their
/// run's config with `--backend`, `--settings`, `--set` and `--authors-rule` applied; the
/// updates they had.
fn load_nets(args: &EvalArgs, mode: policy::Mode) -> Result<(RunConfig, Agent, u64)> {
    let on_backend = args.backend.map(backend::setting).unwrap_or_default();
    let mut set = on_backend.clone();
    let by = match &args.settings {
        Some(path) => {
            merge(&mut set, &read_table(path)?);
            format!("--settings {} and any --set", path.display())
        }
        None => "--set".to_string(),
    };
    for setting in &args.set {
        merge(&mut set, setting);
    }
    if args.authors_rule {
        for setting in [
            format!("policy.q_star={AUTHORS_Q_STAR}"),
            "policy.rule=\"threshold-or-crowded\"".into(),
        ] {
            merge(
                &mut set,
                &parse_setting(&setting).map_err(anyhow::Error::msg)?,
            );
        }
    }
    let (config, mut agent, updates) =
        load_agent(&args.checkpoint, args.config.as_deref(), &set, &by, mode)?;
    for checkpoint in &args.ensemble {
        let (member_config, member, _) =
            load_agent(checkpoint, None, &on_backend, "--backend", mode)?;
        if config_hash(&member_config.net) != config_hash(&config.net)
            || member_config.side() != config.side()
        {
            bail!(
                "--ensemble {}: its nets or heightmap size differ from --checkpoint {}'s",
                checkpoint.display(),
                args.checkpoint.display()
            );
        }
        agent.join_ensemble(member.nets())?;
    }
    Ok((config, agent, updates))
}

/// The cases to test: each arrangement file (with a goal, unless `--goal-agnostic`), then
/// the random scenes.
fn cases(args: &EvalArgs) -> Result<Vec<(String, Scene)>> {
    let mut cases: Vec<(String, Scene)> = named_arrangements(&args.arrangements)?
        .into_iter()
        .map(|(path, name, arrangement)| {
            if arrangement.goal.is_none() && !args.goal_agnostic {
                bail!(
                    "{}: names no goal object (goal = <id>); only --goal-agnostic tests it",
                    path.display()
                );
            }
            Ok((name, Scene::Arrangement(arrangement)))
        })
        .collect::<Result<_>>()?;
    if let Some(objects) = args.random {
        cases.push((format!("random-{objects}"), Scene::Random { objects }));
    }
    if cases.is_empty() {
        bail!("nothing to test: give --arrangements and/or --random");
    }
    Ok(cases)
}

fn write_runs(path: &Path, reports: &[CaseReport]) -> Result<()> {
    let mut lines = String::new();
    for report in reports {
        for (run, record) in report.runs.iter().enumerate() {
            let line = RunLine {
                case: &report.name,
                run,
                outcome: record.outcome(),
                record,
            };
            lines += &serde_json::to_string(&line)?;
            lines.push('\n');
        }
    }
    std::fs::write(path, lines).with_context(|| format!("writing {}", path.display()))
}
