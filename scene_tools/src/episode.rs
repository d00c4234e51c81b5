//! `pushgrasp episode`: a scripted episode on a random scene, so a person can see the whole
//! simulator at work before any learning: grasp the goal across its narrow side, push along
//! it when grasps fail, and write every observation as PNGs with a JSON summary.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use sim::measure::{detect_change, occupancy_ratio};
use sim::{Action, Camera, ObjectId, Primitive, SimConfig, Tabletop};

use crate::pictures;
use sim::MaskShape;

#[derive(Args)]
pub struct EpisodeArgs {
    /// Objects dropped on the table.
    #[arg(long, default_value_t = 10)]
    objects: usize,
    /// Scene and goal seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Heightmap pixel size in metres.
    #[arg(long, default_value_t = 0.002)]
    pixel_size: f32,
    /// Actions before the episode gives up.
    #[arg(long, default_value_t = 10)]
    max_actions: usize,
    /// Output directory (default: logs/episode-seed<S>).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(Serialize)]
struct StepRecord {
    step: usize,
    action: Action,
    grasped: Option<ObjectId>,
    removed: Vec<ObjectId>,
    occupancy_before: f32,
    occupancy_after: f32,
    change_detected: Option<bool>,
    physics_steps: u32,
}

#[derive(Serialize)]
struct EpisodeRecord {
    seed: u64,
    objects: usize,
    goal: ObjectId,
    goal_grasped: bool,
    steps: Vec<StepRecord>,
}

pub fn run(args: &EpisodeArgs) -> Result<()> {
    let config = SimConfig::with_pixel_size(args.pixel_size);
    let (mut tabletop, report) = Tabletop::random(&config, args.objects, args.seed)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("logs/episode-seed{}", args.seed)));
    let camera = Camera::new(tabletop.grid());
    let mut observation = camera.render(&tabletop);
    let visible = observation.visible_ids();
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let goal = *visible
        .get(rng.random_range(0..visible.len().max(1)))
        .context("no object stayed on the table")?;
    println!(
        "scene: {} objects dropped (seed {}), {} left the table; goal: object {goal}",
        report.dropped.len(),
        args.seed,
        report.settle.removed.len()
    );

    let mut steps = Vec::new();
    let mut failed_grasps = 0;
    let mut goal_grasped = false;
    for step in 0..args.max_actions {
        pictures::write_heightmaps(&observation, &out, &format!("step{step:02}"))?;
        let Some(shape) = MaskShape::of(&observation, goal) else {
            println!("step {step}: the goal is hidden or gone; stopping");
            break;
        };
        let action = if failed_grasps < 2 {
            shape.grasp()
        } else {
            shape.push(&observation)
        };
        let outcome = tabletop.act(&action, &observation)?;
        let after = camera.render(&tabletop);
        let change = (action.primitive == Primitive::Push)
            .then(|| detect_change(&observation, &after, goal).detected);
        let record = StepRecord {
            step,
            action,
            grasped: outcome.grasped,
            removed: outcome.removed.clone(),
            occupancy_before: occupancy_ratio(&observation, goal),
            occupancy_after: occupancy_ratio(&after, goal),
            change_detected: change,
            physics_steps: outcome.physics_steps,
        };
        println!(
            "step {step}: {:?} at ({}, {}) rotation {} -> grasped {:?}, occupancy {:.2} -> {:.2}{}",
            action.primitive,
            action.row,
            action.col,
            action.rotation,
            outcome.grasped,
            record.occupancy_before,
            record.occupancy_after,
            change.map_or(String::new(), |c| format!(", change detected: {c}"))
        );
        steps.push(record);
        observation = after;
        match outcome.grasped {
            Some(id) if id == goal => {
                goal_grasped = true;
                break;
            }
            Some(_) => {}
            None if action.primitive == Primitive::Grasp => failed_grasps += 1,
            None => failed_grasps = 0,
        }
    }
    pictures::write_heightmaps(&observation, &out, "final")?;
    let record = EpisodeRecord {
        seed: args.seed,
        objects: args.objects,
        goal,
        goal_grasped,
        steps,
    };
    let summary = out.join("episode.json");
    std::fs::write(&summary, serde_json::to_string_pretty(&record)?)
        .with_context(|| format!("writing {}", summary.display()))?;
    println!(
        "goal grasped: {goal_grasped}; heightmaps and {} written to {}",
        summary.display(),
        out.display()
    );
    Ok(())
}
