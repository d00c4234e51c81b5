//! `pushgrasp bench sim`: the simulator's scene settling, heightmaps and primitives beside one
//! bare rapier step, and its grasp and push quality on seeded trials.

use std::time::{Duration, Instant};

use anyhow::Result;
use clap::Args;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use sim::rapier3d::prelude::{Pose, Rotation, Vector};
use sim::{
    Action, Camera, Heightmaps, MaskShape, Primitive, ROTATIONS, ShapeKind, SimConfig, Tabletop,
};

use super::{median, ms, print_figures, timed};

#[derive(Args)]
pub struct SimBenchArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Repetitions of each timed figure (medians are reported).
    #[arg(long, default_value_t = 20)]
    reps: usize,
    /// Seeded trials of each quality figure.
    #[arg(long, default_value_t = 40)]
    trials: usize,
}

/// The simulator's figures; times are medians.
#[derive(Serialize)]
struct SimFigures {
    settle_ms: f64,
    heightmap_224_ms: f64,
    heightmap_112_ms: f64,
    push_ms: f64,
    grasp_ms: f64,
    action_cycle_ms: f64,
    rapier_step_us: f64,
    /// Share of the primitives' time spent outside rapier's step.
    primitive_outside_step_share: f64,
    physics_steps_per_push: f64,
    physics_steps_per_grasp: f64,
    isolated_cube_grasp_success: f64,
    isolated_cube_grasps: usize,
    clutter_grasp_success: f64,
    clutter_grasps: usize,
    empty_table_grasp_success: f64,
    push_displacement_m: f64,
}

pub fn bench_sim(args: &SimBenchArgs) -> Result<()> {
    let config = SimConfig::default();
    let reps = args.reps.max(1);

    let settle_ms = median(
        (0..reps as u64)
            .map(|seed| ms(timed(|| Tabletop::random(&config, 10, seed)).1))
            .collect(),
    );

    let heightmap_ms = |pixel_size: f32| -> Result<f64> {
        let config = SimConfig::with_pixel_size(pixel_size);
        let (tabletop, _) = Tabletop::random(&config, 10, 0)?;
        let camera = Camera::new(tabletop.grid());
        let mut maps = Heightmaps::new(tabletop.grid());
        Ok(median(
            (0..reps * 10)
                .map(|_| ms(timed(|| camera.render_into(&tabletop, &mut maps)).1))
                .collect(),
        ))
    };
    let heightmap_224_ms = heightmap_ms(0.002)?;
    let heightmap_112_ms = heightmap_ms(0.004)?;

    // Primitives in a 10-object scene, at a pixel on an object, at random rotations.
    let mut push = Vec::new();
    let mut grasp = Vec::new();
    let mut cycle = Vec::new();
    let (mut inside, mut total) = (Duration::ZERO, Duration::ZERO);
    let (mut push_steps, mut grasp_steps) = (Vec::new(), Vec::new());
    for seed in 0..reps as u64 {
        for primitive in [Primitive::Push, Primitive::Grasp] {
            let (mut tabletop, _) = Tabletop::random(&config, 10, seed)?;
            let camera = Camera::new(tabletop.grid());
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let start = Instant::now();
            let before = camera.render(&tabletop);
            let Some((row, col)) = object_pixel(&before, &mut rng) else {
                continue;
            };
            let action = Action {
                primitive,
                rotation: rng.random_range(0..ROTATIONS),
                row,
                col,
            };
            let physics_before = tabletop.physics_time();
            let (outcome, act_time) = timed(|| tabletop.act(&action, &before));
            let outcome = outcome?;
            let _after = camera.render(&tabletop);
            cycle.push(ms(start.elapsed()));
            inside += tabletop.physics_time() - physics_before;
            total += act_time;
            match primitive {
                Primitive::Push => {
                    push.push(ms(act_time));
                    push_steps.push(outcome.physics_steps as f64);
                }
                Primitive::Grasp => {
                    grasp.push(ms(act_time));
                    grasp_steps.push(outcome.physics_steps as f64);
                }
            }
        }
    }

    let rapier_step_us = {
        let (mut tabletop, _) = Tabletop::random(&config, 10, 0)?;
        median(
            (0..reps * 50)
                .map(|_| timed(|| tabletop.step()).1.as_secs_f64() * 1e6)
                .collect(),
        )
    };

    let (isolated_successes, isolated_cube_grasps) = isolated_cube_grasps(&config, args.trials)?;
    let (clutter_successes, clutter_grasps) = clutter_cube_grasps(&config, args.trials)?;
    let empty_successes = empty_table_grasps(&config, args.trials.min(10))?;
    let push_displacement_m = push_displacements(&config, args.trials)?;

    let figures = SimFigures {
        settle_ms,
        heightmap_224_ms,
        heightmap_112_ms,
        push_ms: median(push),
        grasp_ms: median(grasp),
        action_cycle_ms: median(cycle),
        rapier_step_us,
        primitive_outside_step_share: 1.0 - inside.as_secs_f64() / total.as_secs_f64(),
        physics_steps_per_push: median(push_steps),
        physics_steps_per_grasp: median(grasp_steps),
        isolated_cube_grasp_success: isolated_successes as f64 / isolated_cube_grasps as f64,
        isolated_cube_grasps,
        clutter_grasp_success: clutter_successes as f64 / clutter_grasps.max(1) as f64,
        clutter_grasps,
        empty_table_grasp_success: empty_successes as f64 / args.trials.min(10) as f64,
        push_displacement_m,
    };
    print_figures(&serde_json::to_value(&figures)?, args.json)
}

/// A random pixel on some object, if any is visible.
fn object_pixel(maps: &Heightmaps, rng: &mut ChaCha8Rng) -> Option<(usize, usize)> {
    let on: Vec<usize> = (0..maps.ids.len()).filter(|&i| maps.ids[i] != 0).collect();
    (!on.is_empty()).then(|| {
        let i = on[rng.random_range(0..on.len())];
        (i / maps.side(), i % maps.side())
    })
}

/// Adds cube `id` within 10 cm of the workspace centre with a random yaw, released at
/// height `z`, and settles.
fn add_random_cube(tabletop: &mut Tabletop, id: u8, z: f32, rng: &mut ChaCha8Rng) -> Result<()> {
    let x = sim::workspace::CENTRE[0] + rng.random_range(-0.1..0.1);
    let y = sim::workspace::CENTRE[1] + rng.random_range(-0.1..0.1);
    let yaw = rng.random_range(0.0..std::f32::consts::TAU);
    let pose = Pose::from_parts(Vector::new(x, y, z), Rotation::from_rotation_z(yaw));
    tabletop.add_object(id, ShapeKind::Cube, sim::SLOT_COLOURS[0], pose)?;
    tabletop.settle();
    Ok(())
}

/// A lone cube resting on the table.
fn lone_cube(config: &SimConfig, rng: &mut ChaCha8Rng) -> Result<Tabletop> {
    let mut tabletop = Tabletop::new(config)?;
    add_random_cube(&mut tabletop, 1, 0.025, rng)?;
    Ok(tabletop)
}

/// Grasps object `id` at the centroid of its visible pixels at a random rotation, if at least
/// `min_visible` of its pixels are seen: whether it was the one grasped.
fn grasp_visible(
    tabletop: &mut Tabletop,
    id: u8,
    min_visible: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Option<bool>> {
    let maps = Camera::new(tabletop.grid()).render(tabletop);
    let Some(MaskShape { row, col, .. }) =
        MaskShape::of(&maps, id).filter(|shape| shape.pixels >= min_visible)
    else {
        return Ok(None);
    };
    let action = Action {
        primitive: Primitive::Grasp,
        rotation: rng.random_range(0..ROTATIONS),
        row,
        col,
    };
    Ok(Some(tabletop.act(&action, &maps)?.grasped == Some(id)))
}

/// Grasps at a lone cube's centre at random angles: (successes, trials).
fn isolated_cube_grasps(config: &SimConfig, trials: usize) -> Result<(usize, usize)> {
    let mut successes = 0;
    for seed in 0..trials as u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(1000 + seed);
        let mut tabletop = lone_cube(config, &mut rng)?;
        let grasped = grasp_visible(&mut tabletop, 1, 1, &mut rng)?;
        successes += usize::from(grasped.expect("a lone cube is visible"));
    }
    Ok((successes, trials))
}

/// Grasps at the visible centre of a cube dropped last among 10 objects, at random angles,
/// in scenes where at least 80% of the cube's top is seen: (successes, trials).
fn clutter_cube_grasps(config: &SimConfig, trials: usize) -> Result<(usize, usize)> {
    let (mut successes, mut attempts) = (0, 0);
    let mostly_visible = (0.8 * (0.05 / config.pixel_size).powi(2)) as usize;
    for seed in 2000..2000 + 10 * trials as u64 {
        if attempts == trials {
            break;
        }
        let (mut tabletop, _) = Tabletop::random(config, 9, seed)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        add_random_cube(&mut tabletop, 10, config.drop_height, &mut rng)?;
        if let Some(grasped) = grasp_visible(&mut tabletop, 10, mostly_visible, &mut rng)? {
            attempts += 1;
            successes += usize::from(grasped);
        }
    }
    Ok((successes, attempts))
}

/// Grasps on an empty table, which must all fail: the number that succeeded.
fn empty_table_grasps(config: &SimConfig, trials: usize) -> Result<usize> {
    let mut successes = 0;
    for seed in 0..trials as u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(3000 + seed);
        let mut tabletop = Tabletop::new(config)?;
        let maps = Camera::new(tabletop.grid()).render(&tabletop);
        let side = maps.side();
        let action = Action {
            primitive: Primitive::Grasp,
            rotation: rng.random_range(0..ROTATIONS),
            row: rng.random_range(side / 4..3 * side / 4),
            col: rng.random_range(side / 4..3 * side / 4),
        };
        successes += usize::from(tabletop.act(&action, &maps)?.grasp_succeeded());
    }
    Ok(successes)
}

/// Median displacement of a lone cube pushed through its centre from 5 cm before it.
fn push_displacements(config: &SimConfig, trials: usize) -> Result<f64> {
    let mut displacements = Vec::new();
    for seed in 0..trials as u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(4000 + seed);
        let mut tabletop = lone_cube(config, &mut rng)?;
        let before = tabletop.object(1).expect("cube").pose.translation;
        let maps = Camera::new(tabletop.grid()).render(&tabletop);
        let rotation = rng.random_range(0..ROTATIONS);
        let angle = sim::rotation_angle(rotation);
        let start = before - 0.05 * Vector::new(angle.cos(), angle.sin(), 0.0);
        let Some((row, col)) = tabletop.grid().pixel_of(start.x, start.y) else {
            continue;
        };
        let action = Action {
            primitive: Primitive::Push,
            rotation,
            row,
            col,
        };
        tabletop.act(&action, &maps)?;
        let after = tabletop.object(1).map_or(before, |o| o.pose.translation);
        displacements.push(((after - before).truncate().length()) as f64);
    }
    Ok(median(displacements))
}
