//! `pushgrasp scene grasps`: how many of the direct grasps of an arrangement's goal succeed,
//! each tried in the simulator from the arranged scene (no push before it). A case where none
//! succeeds needs a push; where some always do, a grasp net that tells them apart picks the
//! goal at once. The share that succeeds is what a policy grasping the goal at a random
//! pixel and angle gets.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;
use clap::builder::RangedU64ValueParser;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;
use sim::{Action, Arrangement, Camera, ObjectId, Primitive, ROTATIONS, SimConfig, Tabletop};

use crate::eval::named_arrangements;

#[derive(Args)]
pub struct GraspsArgs {
    /// Arrangement files (our TOML, with a goal) or directories of them.
    #[arg(long, num_args = 1.., required = true)]
    arrangements: Vec<PathBuf>,
    /// Heightmap pixel size in metres (the stage configs: 0.004, 112 x 112).
    #[arg(long, default_value_t = 0.004)]
    pixel_size: f32,
    /// Try every `stride`-th pixel of the goal's mask, in rows and in columns.
    #[arg(long, default_value_t = 2, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    stride: usize,
    /// Copies of the scene each grasp is tried on, jittered as eval's runs are (1 mm, 1 degree).
    #[arg(long, default_value_t = 4, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    jitters: usize,
    /// The jitter derives from this seed and the case's place in the list.
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
}

pub fn run(args: &GraspsArgs) -> Result<()> {
    let sim = SimConfig::with_pixel_size(args.pixel_size);
    sim.grid()?;
    let jitter = agent::EvalConfig::default();
    let mut cases = Vec::new();
    for (index, (path, name, arrangement)) in named_arrangements(&args.arrangements)?
        .into_iter()
        .enumerate()
    {
        let Some(goal) = arrangement.goal else {
            bail!("{}: names no goal object (goal = <id>)", path.display());
        };
        let mut rng = ChaCha8Rng::seed_from_u64(args.seed.wrapping_add(index as u64));
        let copies: Vec<Arrangement> = (0..args.jitters)
            .map(|_| arrangement.jittered(jitter.jitter_m, jitter.jitter_rad, &mut rng))
            .collect();
        let candidates = candidates(&sim, &arrangement, goal, args.stride)?;
        if candidates.is_empty() {
            bail!(
                "{}: the goal, object {goal}, is not seen from above once the scene settles",
                path.display()
            );
        }
        let picks: Vec<usize> = candidates
            .par_iter()
            .map(|action| {
                copies
                    .iter()
                    .map(|copy| picks_goal(&sim, copy, goal, action).map(usize::from))
                    .sum::<Result<usize>>()
            })
            .collect::<Result<_>>()?;
        let share = |count: usize| count as f64 / candidates.len() as f64;
        cases.push(CaseGrasps {
            case: name,
            goal,
            candidates: candidates.len(),
            always: share(picks.iter().filter(|&&p| p == args.jitters).count()),
            never: share(picks.iter().filter(|&&p| p == 0).count()),
            success: share(picks.iter().sum()) / args.jitters as f64,
        });
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({ "stride": args.stride, "jitters": args.jitters, "cases": cases })
        );
    } else {
        print_table(&cases, args);
    }
    Ok(())
}

/// Grasps at every `stride`-th pixel of the goal's mask in the settled, unjittered scene,
/// at each of the distinct jaw angles.
fn candidates(
    sim: &SimConfig,
    arrangement: &Arrangement,
    goal: ObjectId,
    stride: usize,
) -> Result<Vec<Action>> {
    let mut tabletop = Tabletop::from_arrangement(sim, arrangement)?;
    tabletop.settle();
    let maps = Camera::new(tabletop.grid()).render(&tabletop);
    let side = maps.side();
    let mask = maps.goal_mask(goal);
    Ok((0..mask.len())
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
        .collect())
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

fn print_table(cases: &[CaseGrasps], args: &GraspsArgs) {
    println!(
        "Direct grasps of the goal: every {} px of its mask x {} jaw angles, each on {} jittered copies",
        args.stride,
        ROTATIONS / 2,
        args.jitters
    );
    println!(
        "{:<20} {:>5} {:>11} {:>8} {:>8} {:>8}",
        "case", "goal", "candidates", "always", "never", "success"
    );
    let percent = |share: f64| format!("{:.1}%", 100.0 * share);
    for case in cases {
        println!(
            "{:<20} {:>5} {:>11} {:>8} {:>8} {:>8}",
            case.case,
            case.goal,
            case.candidates,
            percent(case.always),
            percent(case.never),
            percent(case.success)
        );
    }
    let n = cases.len() as f64;
    let mean = |field: fn(&CaseGrasps) -> f64| cases.iter().map(field).sum::<f64>() / n;
    println!(
        "{:<20} {:>5} {:>11} {:>8} {:>8} {:>8}",
        "average",
        "",
        "",
        percent(mean(|c| c.always)),
        percent(mean(|c| c.never)),
        percent(mean(|c| c.success))
    );
}
