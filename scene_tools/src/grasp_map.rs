//! `pushgrasp scene grasps`: how many of the direct grasps of an arrangement's goal succeed,
//! each tried in the simulator from the arranged scene (no push before it). A case where none
//! succeeds needs a push; where some always do, a grasp net that tells them apart picks the
//! goal at once. The share that succeeds is what a policy grasping the goal at a random
//! pixel and angle gets; the same among the grasps that stay a margin inside the goal's
//! mask is what `[policy] grasp_margin` leaves the policy. A scripted grasp (the mask's
//! centroid, jaws across its narrow side) shows what a grasp made without learning gets.
//! With a checkpoint, its grasp net is scored against those outcomes: how well its Q ranks
//! the grasps that always succeed above those that never do (AUC, target 0.85), and how its
//! best-scored grasp fares. The grasp ranking of packed clusters the net never trained on:
//! `--random 12 --objects 5 --row 4 --lines 2 --checkpoint <run>/checkpoint`.
//!
//! The net's score is `net_score.rs`; the grasps measured and the table printed share their
//! records and are used nowhere else, so they stay here together.

mod net_score;

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;
use clap::builder::RangedU64ValueParser;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;
use sim::{
    Action, Arrangement, Camera, Heightmaps, ObjectId, Primitive, ROTATIONS, SimConfig, Tabletop,
};

use crate::rows::RowArgs;
use net_score::{NetScore, TOP_K, score_net};
use rundir::{load_agent, named_arrangements};
use sim::MaskShape;

/// Margins (metres) of `[policy] grasp_margin` at which the success of the grasps the
/// policy may still make is shown.
const MARGINS: [f32; 3] = [0.004, 0.008, 0.012];

/// Random scenes' seeds start here (plus `--seed`), apart from the jitter seeds of the
/// case list, which count up from `--seed`.
const RANDOM_SCENE_SEEDS: u64 = 1 << 32;

#[derive(Args)]
#[command(group(clap::ArgGroup::new("scenes").args(["arrangements", "random"]).required(true).multiple(true)))]
pub struct GraspsArgs {
    /// Arrangement files (our TOML, with a goal) or directories of them.
    #[arg(long, num_args = 1..)]
    arrangements: Vec<PathBuf>,
    /// Also this many random scenes, as training drops them (`--objects` each), with a
    /// visible object drawn as the goal: how the net does on the scenes it learns from.
    #[arg(long, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    random: Option<usize>,
    /// Objects dropped in each random scene (stage 1 drops 5, stages 2 and 3 drop 10).
    #[arg(long, default_value_t = 10, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    objects: usize,
    /// Random scenes' touching rows; the goal is then one of their blocks.
    #[command(flatten)]
    rows: RowArgs,
    /// Heightmap pixel size in metres (the stage configs: 0.004, 112 x 112); with
    /// --checkpoint, the simulator of its run config.
    #[arg(long, default_value_t = 0.004, conflicts_with = "checkpoint")]
    pixel_size: f32,
    /// Score this checkpoint's grasp net against the outcomes (a run's `checkpoint/`).
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// The config the checkpoint was trained with (default: `config.toml` in its run
    /// directory).
    #[arg(long, requires = "checkpoint")]
    config: Option<PathBuf>,
    /// Try every `stride`-th pixel of the goal's mask, in rows and in columns.
    #[arg(long, default_value_t = 2, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    stride: usize,
    /// Copies of the scene each grasp is tried on, jittered as eval's runs are (1 mm, 1 degree).
    #[arg(long, default_value_t = 4, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    jitters: usize,
    /// The jitter derives from this seed and the case's place in the list, and so do the
    /// random scenes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

/// One case's grasps of its goal.
#[derive(Debug, Serialize)]
struct CaseGrasps {
    case: String,
    goal: ObjectId,
    /// Grasps tried: mask pixels times jaw angles (k and k + 8 are the same grasp).
    candidates: usize,
    /// Shares of the candidates that picked the goal on every copy, and on none.
    always: f64,
    never: f64,
    /// Share of all tries that picked the goal.
    success: f64,
    /// The same among the grasps a grasp margin keeps, for each of [`MARGINS`] (none when
    /// no candidate is left).
    inside: Vec<MarginSuccess>,
    /// Share of tries of the scripted grasp ([`MaskShape::grasp`]) that picked the goal.
    scripted: f64,
    /// With a checkpoint: how its grasp net scores these grasps.
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    net: Option<NetScore>,
}

#[derive(Debug, Serialize)]
struct MarginSuccess {
    margin: f32,
    success: Option<f64>,
}

/// The AUC a grasp net should reach on packed clusters it never trained on (random scenes'
/// seeds start at 2^32, where no actor's scenes are drawn): the goal of learning to rank
/// grasps in clutter.
const AUC_TARGET: f64 = 0.85;

/// The cases' figures averaged (each over the cases that have it): the grasp net's
/// ranking of the goal's grasps against grasps at random.
#[derive(Debug, Serialize)]
struct Summary {
    always: f64,
    never: f64,
    /// A grasp at a random pixel and angle of the goal.
    success: f64,
    /// For each of [`MARGINS`].
    inside: Vec<Option<f64>>,
    scripted: f64,
    /// With a checkpoint: the mean of the cases' AUCs (over the cases that have one), the
    /// best-scored grasp's and the top [`TOP_K`]'s success.
    #[serde(skip_serializing_if = "Option::is_none")]
    net_auc: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    net_best: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    net_top_k: Option<f64>,
}

impl Summary {
    fn of(cases: &[CaseGrasps]) -> Self {
        let mean = |field: &dyn Fn(&CaseGrasps) -> Option<f64>| {
            let values: Vec<f64> = cases.iter().filter_map(field).collect();
            (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
        };
        let share = |field: fn(&CaseGrasps) -> f64| mean(&|c| Some(field(c))).unwrap_or(0.0);
        Self {
            always: share(|c| c.always),
            never: share(|c| c.never),
            success: share(|c| c.success),
            inside: (0..MARGINS.len())
                .map(|k| mean(&|c| c.inside[k].success))
                .collect(),
            scripted: share(|c| c.scripted),
            net_auc: mean(&|c| c.net.as_ref().and_then(|n| n.net_auc)),
            net_best: mean(&|c| c.net.as_ref().map(|n| n.net_best)),
            net_top_k: mean(&|c| c.net.as_ref().map(|n| n.net_top_k)),
        }
    }
}

pub fn run(args: &GraspsArgs) -> Result<()> {
    let cases = measure(args)?;
    let summary = Summary::of(&cases);
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "stride": args.stride,
                "jitters": args.jitters,
                "cases": cases,
                "average": summary,
                "net_auc_target": AUC_TARGET,
            })
        );
    } else {
        print_table(&cases, &summary, args);
    }
    Ok(())
}

/// Every case's grasps of its goal, tried.
fn measure(args: &GraspsArgs) -> Result<Vec<CaseGrasps>> {
    let (sim, agent) = match &args.checkpoint {
        Some(checkpoint) => {
            let (config, agent, _) = load_agent(
                checkpoint,
                args.config.as_deref(),
                &toml::Table::new(),
                "no settings",
                policy::Mode::GraspOnly,
            )?;
            (config.sim, Some(agent))
        }
        None => (SimConfig::with_pixel_size(args.pixel_size), None),
    };
    // A pixel size with no grid fails here, before any scene is built.
    sim.grid()?;
    // The copies move as eval's runs do.
    let eval = agent::EvalConfig::default();
    let mut scenes: Vec<(String, String, Arrangement)> = named_arrangements(&args.arrangements)?
        .into_iter()
        .map(|(path, name, arrangement)| (path.display().to_string(), name, arrangement))
        .collect();
    for index in 0..args.random.unwrap_or(0) {
        let (name, arrangement) = random_scene(args, &sim, index)?;
        scenes.push((name.clone(), name, arrangement));
    }
    let mut cases = Vec::new();
    for (index, (source, name, arrangement)) in scenes.into_iter().enumerate() {
        let Some(goal) = arrangement.goal else {
            bail!("{source}: names no goal object (goal = <id>)");
        };
        let mut rng = ChaCha8Rng::seed_from_u64(args.seed.wrapping_add(index as u64));
        let copies: Vec<Arrangement> = (0..args.jitters)
            .map(|_| arrangement.jittered(eval.jitter_m, eval.jitter_rad, &mut rng))
            .collect();
        let mut tabletop = Tabletop::from_arrangement(&sim, &arrangement)?;
        tabletop.settle();
        let maps = Camera::new(tabletop.grid()).render(&tabletop);
        let candidates = candidates(&maps, goal, args.stride);
        if candidates.is_empty() {
            bail!(
                "{source}: the goal, object {goal}, is not seen from above once the scene settles"
            );
        }
        let tries = |action: &Action| -> Result<usize> {
            copies
                .iter()
                .map(|copy| picks_goal(&sim, copy, goal, action).map(usize::from))
                .sum()
        };
        let picks: Vec<usize> = candidates.par_iter().map(tries).collect::<Result<_>>()?;
        let scripted = MaskShape::of(&maps, goal)
            .map(|shape| tries(&shape.grasp()))
            .transpose()?
            .unwrap_or(0) as f64
            / args.jitters as f64;
        let net = match &agent {
            Some(agent) => Some(score_net(
                agent,
                &maps,
                goal,
                &candidates,
                &picks,
                args.jitters,
            )?),
            None => None,
        };
        let inside = inside_margins(&maps, goal, &candidates, &picks, args.jitters);
        let share = |count: usize| count as f64 / candidates.len() as f64;
        cases.push(CaseGrasps {
            case: name,
            goal,
            candidates: candidates.len(),
            always: share(picks.iter().filter(|&&p| p == args.jitters).count()),
            never: share(picks.iter().filter(|&&p| p == 0).count()),
            success: share(picks.iter().sum()) / args.jitters as f64,
            inside,
            scripted,
            net,
        });
    }
    Ok(cases)
}

/// Random scene `index` of `args`, named, with a goal seen from above (with rows, one of
/// their blocks: ids 1 to `row`).
fn random_scene(args: &GraspsArgs, sim: &SimConfig, index: usize) -> Result<(String, Arrangement)> {
    let name = format!("random-{}{}-{index}", args.objects, args.rows.label());
    let seed = args
        .seed
        .wrapping_add(RANDOM_SCENE_SEEDS)
        .wrapping_add(index as u64);
    let (tabletop, _) = Tabletop::random_with_rows(sim, args.objects, args.rows.rows(), seed)?;
    let visible: Vec<ObjectId> = Camera::new(tabletop.grid())
        .render(&tabletop)
        .visible_ids()
        .into_iter()
        .filter(|&id| args.rows.row < 2 || usize::from(id) <= args.rows.row)
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let Some(&goal) = visible.get(rng.random_range(0..visible.len().max(1))) else {
        bail!("{name} (seed {seed}): no object is seen from above");
    };
    let arrangement = tabletop.to_arrangement(Some(name.clone()), Some(goal));
    Ok((name, arrangement))
}

/// The success of the candidates inside each of [`MARGINS`]' grasp regions (None where the
/// region keeps none); `picks[i]` is how many of the `jitters` copies candidate `i` picked.
fn inside_margins(
    maps: &Heightmaps,
    goal: ObjectId,
    candidates: &[Action],
    picks: &[usize],
    jitters: usize,
) -> Vec<MarginSuccess> {
    MARGINS
        .iter()
        .map(|&margin| {
            let region = policy::grasp_region(maps, goal, margin);
            let kept: Vec<usize> = (0..candidates.len())
                .filter(|&i| region[candidates[i].row * maps.side() + candidates[i].col])
                .collect();
            let success = (!kept.is_empty()).then(|| {
                kept.iter().map(|&i| picks[i]).sum::<usize>() as f64 / (kept.len() * jitters) as f64
            });
            MarginSuccess { margin, success }
        })
        .collect()
}

/// Grasps at every `stride`-th pixel of the goal's mask in `maps`, at each of the distinct
/// jaw angles.
fn candidates(maps: &Heightmaps, goal: ObjectId, stride: usize) -> Vec<Action> {
    let side = maps.side();
    let mask = maps.goal_mask(goal);
    (0..mask.len())
        .filter(|&i| {
            mask[i] && (i / side).is_multiple_of(stride) && (i % side).is_multiple_of(stride)
        })
        .flat_map(|i| {
            (0..ROTATIONS / 2).map(move |rotation| Action {
                primitive: Primitive::Grasp,
                rotation,
                row: i / side,
                col: i % side,
            })
        })
        .collect()
}

/// Whether `action` on the settled scene of `arrangement` lifts the goal.
fn picks_goal(
    sim: &SimConfig,
    arrangement: &Arrangement,
    goal: ObjectId,
    action: &Action,
) -> Result<bool> {
    let mut tabletop = Tabletop::from_arrangement(sim, arrangement)?;
    tabletop.settle();
    let maps = Camera::new(tabletop.grid()).render(&tabletop);
    Ok(tabletop.act(action, &maps)?.grasped == Some(goal))
}

fn print_table(cases: &[CaseGrasps], summary: &Summary, args: &GraspsArgs) {
    println!(
        "Direct grasps of the goal: every {} px of its mask x {} jaw angles, each on {} jittered copies",
        args.stride,
        ROTATIONS / 2,
        args.jitters
    );
    let percent = |share: f64| format!("{:.1}%", 100.0 * share);
    let row = |case: &str,
               goal: &str,
               candidates: &str,
               shares: [f64; 3],
               inside: Vec<Option<f64>>,
               scripted: f64,
               net: Option<[String; 3]>| {
        let [always, never, success] = shares.map(percent);
        let inside: String = inside
            .into_iter()
            .map(|s| format!(" {:>8}", s.map_or("-".into(), percent)))
            .collect();
        let scripted = percent(scripted);
        let net = net.map_or(String::new(), |[auc, best, top]| {
            format!(" {auc:>8} {best:>9} {top:>9}")
        });
        println!(
            "{case:<20} {goal:>5} {candidates:>11} {always:>8} {never:>8} {success:>8}{inside} {scripted:>9}{net}"
        );
    };
    let scored = summary.net_best.is_some();
    let header = if scored {
        format!(
            " {:>8} {:>9} {:>9}",
            "net AUC",
            "net best",
            format!("net top{TOP_K}")
        )
    } else {
        String::new()
    };
    let margins: String = MARGINS
        .iter()
        .map(|m| format!(" {:>8}", format!("in {}mm", (m * 1000.0).round())))
        .collect();
    println!(
        "{:<20} {:>5} {:>11} {:>8} {:>8} {:>8}{margins} {:>9}{header}",
        "case", "goal", "candidates", "always", "never", "success", "scripted"
    );
    let auc = |auc: Option<f64>| auc.map_or("-".into(), |a| format!("{a:.2}"));
    for case in cases {
        row(
            &case.case,
            &case.goal.to_string(),
            &case.candidates.to_string(),
            [case.always, case.never, case.success],
            case.inside.iter().map(|m| m.success).collect(),
            case.scripted,
            case.net
                .as_ref()
                .map(|n| [auc(n.net_auc), percent(n.net_best), percent(n.net_top_k)]),
        );
    }
    let net = scored.then(|| {
        [
            auc(summary.net_auc),
            percent(summary.net_best.unwrap_or(0.0)),
            percent(summary.net_top_k.unwrap_or(0.0)),
        ]
    });
    row(
        "average",
        "",
        "",
        [summary.always, summary.never, summary.success],
        summary.inside.clone(),
        summary.scripted,
        net,
    );
    if scored {
        println!(
            "the net's AUC (always against never picks the goal): {}, target >= {AUC_TARGET}",
            auc(summary.net_auc)
        );
    }
}
