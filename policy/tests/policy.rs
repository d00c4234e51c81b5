//! The hierarchical policy on rendered scenes: the Q* rule, the push budget, where pushes and
//! grasps may go, exploration, the epsilon schedule and determinism.

mod common;

use common::cube;
use sim::workspace::CENTRE;
use std::collections::HashSet;

use policy::{
    Decision, Mode, PUSH_START_MAX_HEIGHT, PolicyConfig, PolicyError, PolicyInput, QMaps, Reason,
    Rule, choose, grasp_region, trial_grasps, valid_push_starts,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sim::{
    Action, Camera, Heightmaps, ObjectId, PixelGrid, Primitive, ROTATIONS, SimConfig, Tabletop,
};

const GOAL: ObjectId = 1;
const PIXEL_SIZE: f32 = 0.004;

/// The goal cube at the centre with three other cubes around it, 112 x 112.
fn scene() -> Heightmaps {
    let mut tabletop = Tabletop::new(&SimConfig::with_pixel_size(PIXEL_SIZE)).unwrap();
    cube(&mut tabletop, GOAL, 0.0, 0.0, 0.025);
    cube(&mut tabletop, 2, 0.1, 0.0, 0.025);
    cube(&mut tabletop, 3, -0.1, 0.05, 0.025);
    cube(&mut tabletop, 4, 0.0, -0.12, 0.025);
    Camera::new(tabletop.grid()).render(&tabletop)
}

/// The pixel under the point offset (dx, dy) from the workspace centre.
fn pixel(obs: &Heightmaps, dx: f32, dy: f32) -> (usize, usize) {
    obs.grid.pixel_of(CENTRE[0] + dx, CENTRE[1] + dy).unwrap()
}

/// Q maps of the observation's size, `base` everywhere but the given (rotation, pixel)s.
fn maps(obs: &Heightmaps, base: f32, set: &[(u8, (usize, usize), f32)]) -> QMaps {
    let side = obs.side();
    let mut values = vec![base; ROTATIONS as usize * side * side];
    for &(rotation, (row, col), q) in set {
        values[(rotation as usize * side + row) * side + col] = q;
    }
    QMaps::new(ROTATIONS, side, values).unwrap()
}

/// Q maps of uniform random values in `range`.
fn random_maps(obs: &Heightmaps, range: std::ops::Range<f32>, rng: &mut ChaCha8Rng) -> QMaps {
    let len = ROTATIONS as usize * obs.side() * obs.side();
    let values = (0..len).map(|_| rng.random_range(range.clone())).collect();
    QMaps::new(ROTATIONS, obs.side(), values).unwrap()
}

fn input<'a>(
    obs: &'a Heightmaps,
    grasp: &'a QMaps,
    push: Option<&'a QMaps>,
    pushes_so_far: usize,
) -> PolicyInput<'a> {
    PolicyInput {
        obs,
        goal: GOAL,
        grasp,
        push,
        pushes_so_far,
        push_length: 0.13,
        landing_view: None,
        failed_grasps: &[],
        grasp_failed_since_push: false,
    }
}

/// A greedy choice (epsilon 0) in push-grasp mode with the default config.
fn greedy(input: &PolicyInput) -> Decision {
    greedy_with(&PolicyConfig::default(), Mode::PushGrasp, input)
}

/// A greedy choice (epsilon 0) with `config` in `mode`.
fn greedy_with(config: &PolicyConfig, mode: Mode, input: &PolicyInput) -> Decision {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    choose(config, mode, input, 0.0, &mut rng).unwrap()
}

fn at(decision: &Decision) -> (u8, (usize, usize)) {
    let a = decision.action;
    (a.rotation, (a.row, a.col))
}

/// The standard Q maps: the goal's grasp Q is `q` at rotation 3 of its centre pixel, a
/// non-goal cube has a higher grasp Q (which must not count), and the best push starts on a
/// cube (which must not be taken) while the best valid one is on the table.
struct Fixture {
    obs: Heightmaps,
    goal_pixel: (usize, usize),
    table_pixel: (usize, usize),
    push: QMaps,
}

impl Fixture {
    fn new() -> Self {
        let obs = scene();
        let goal_pixel = pixel(&obs, 0.0, 0.0);
        let table_pixel = pixel(&obs, 0.17, 0.17);
        let other_cube = pixel(&obs, 0.1, 0.0);
        assert_eq!(obs.ids[obs.index(goal_pixel.0, goal_pixel.1)], GOAL);
        assert_eq!(obs.ids[obs.index(table_pixel.0, table_pixel.1)], 0);
        assert_eq!(obs.ids[obs.index(other_cube.0, other_cube.1)], 2);
        let push = maps(&obs, 0.0, &[(7, table_pixel, 1.0), (2, other_cube, 9.0)]);
        Self {
            obs,
            goal_pixel,
            table_pixel,
            push,
        }
    }

    fn grasp(&self, q: f32) -> QMaps {
        let other_cube = pixel(&self.obs, 0.1, 0.0);
        maps(
            &self.obs,
            0.0,
            &[(3, self.goal_pixel, q), (5, other_cube, 5.0)],
        )
    }
}

#[test]
fn the_goal_is_grasped_just_above_q_star_and_pushed_for_at_or_below_it() {
    let f = Fixture::new();
    let grasp = f.grasp(1.81);
    let d = greedy(&input(&f.obs, &grasp, Some(&f.push), 0));
    assert_eq!(d.action.primitive, Primitive::Grasp);
    assert_eq!(at(&d), (3, f.goal_pixel));
    assert_eq!(
        (d.reason, d.goal_grasp_q, d.predicted_q),
        (Reason::AboveThreshold, 1.81, 1.81)
    );
    assert!(!d.explored && d.goal_visible);

    for q in [1.79, 1.8] {
        let grasp = f.grasp(q);
        let d = greedy(&input(&f.obs, &grasp, Some(&f.push), 0));
        assert_eq!(d.action.primitive, Primitive::Push, "q {q}");
        // The best push over valid starts, not the better one on top of a cube.
        assert_eq!(at(&d), (7, f.table_pixel));
        assert_eq!(
            (d.reason, d.goal_grasp_q, d.predicted_q),
            (Reason::BelowThreshold, q, 1.0)
        );
    }
}

#[test]
fn vpgs_rule_takes_the_primitive_with_the_higher_q_whatever_q_star() {
    let f = Fixture::new();
    let vpg = PolicyConfig {
        rule: Rule::HigherQ,
        ..PolicyConfig::default()
    };
    let decide = |grasp_q: f32, pushes: usize| {
        let grasp = f.grasp(grasp_q);
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let i = input(&f.obs, &grasp, Some(&f.push), pushes);
        choose(&vpg, Mode::PushGrasp, &i, 0.0, &mut rng).unwrap()
    };
    // The best valid push is 1.0 (the 9.0 on a cube does not count, nor the other cube's 5.0
    // grasp): below it the goal is pushed for even though nothing is near Q*, ...
    let d = decide(0.99, 0);
    assert_eq!(
        (d.action.primitive, d.reason),
        (Primitive::Push, Reason::PushQHigher)
    );
    assert_eq!(at(&d), (7, f.table_pixel));
    assert_eq!(d.best_push_q, Some(1.0));
    // ... at or above it the goal is grasped though its Q is far below Q*.
    for q in [1.0, 1.2] {
        let d = decide(q, 0);
        assert_eq!(
            (d.action.primitive, d.reason),
            (Primitive::Grasp, Reason::GraspQHigher)
        );
        assert_eq!(at(&d), (3, f.goal_pixel));
    }
    // The push budget binds as under the paper's rule.
    let d = decide(0.5, 5);
    assert_eq!(
        (d.action.primitive, d.reason),
        (Primitive::Grasp, Reason::PushBudgetSpent)
    );
}

/// The goal cube with cubes against three of its sides: more than 0.3 of its ring occupied.
fn crowded_scene() -> Heightmaps {
    let mut tabletop = Tabletop::new(&SimConfig::with_pixel_size(PIXEL_SIZE)).unwrap();
    cube(&mut tabletop, GOAL, 0.0, 0.0, 0.025);
    cube(&mut tabletop, 2, 0.055, 0.0, 0.025);
    cube(&mut tabletop, 3, 0.0, 0.055, 0.025);
    cube(&mut tabletop, 4, -0.055, 0.0, 0.025);
    let crowded = Camera::new(tabletop.grid()).render(&tabletop);
    assert!(sim::measure::occupancy_ratio(&crowded, GOAL) > 0.3);
    crowded
}

#[test]
fn the_authors_test_rule_pushes_a_goal_with_a_crowded_border_whatever_its_q() {
    let authors = PolicyConfig {
        rule: Rule::ThresholdOrCrowded,
        q_star: 1.5,
        ..PolicyConfig::default()
    };
    // The fixture's neighbours stand 10 cm off: the goal's 2 cm ring is free, so the rule is
    // the threshold alone, at its own Q*.
    let f = Fixture::new();
    for (q, primitive, reason) in [
        (1.6, Primitive::Grasp, Reason::AboveThreshold),
        (1.5, Primitive::Push, Reason::BelowThreshold),
    ] {
        let grasp = f.grasp(q);
        let d = greedy_with(
            &authors,
            Mode::PushGrasp,
            &input(&f.obs, &grasp, Some(&f.push), 0),
        );
        assert_eq!((d.action.primitive, d.reason), (primitive, reason), "q {q}");
    }

    // A cube against two sides of the goal fills more than 0.3 of its ring: a push, even at
    // a grasp Q that passes every threshold, until the push budget is spent.
    let crowded = crowded_scene();
    let goal_pixel = pixel(&crowded, 0.0, 0.0);
    let grasp = maps(&crowded, 0.0, &[(3, goal_pixel, 1.9)]);
    let push = maps(&crowded, 0.0, &[(7, pixel(&crowded, 0.0, -0.1), 1.0)]);
    let decide = |config: &PolicyConfig, pushes: usize| {
        greedy_with(
            config,
            Mode::PushGrasp,
            &input(&crowded, &grasp, Some(&push), pushes),
        )
    };
    let d = decide(&authors, 0);
    assert_eq!(
        (d.action.primitive, d.reason),
        (Primitive::Push, Reason::BorderCrowded)
    );
    let d = decide(&authors, 5);
    assert_eq!(
        (d.action.primitive, d.reason),
        (Primitive::Grasp, Reason::PushBudgetSpent)
    );
    // The paper's rule grasps there; grasp-only mode never measures the ring.
    let d = decide(&PolicyConfig::default(), 0);
    assert_eq!(d.reason, Reason::AboveThreshold);
    let d = greedy_with(&authors, Mode::GraspOnly, &input(&crowded, &grasp, None, 0));
    assert_eq!(d.reason, Reason::GraspOnlyMode);
}

#[test]
fn a_spent_push_budget_forces_a_grasp() {
    let f = Fixture::new();
    let grasp = f.grasp(1.0);
    let d = greedy(&input(&f.obs, &grasp, Some(&f.push), 4));
    assert_eq!(
        (d.action.primitive, d.reason),
        (Primitive::Push, Reason::BelowThreshold)
    );
    for pushes in [5, 6] {
        let d = greedy(&input(&f.obs, &grasp, Some(&f.push), pushes));
        assert_eq!(
            (d.action.primitive, d.reason),
            (Primitive::Grasp, Reason::PushBudgetSpent)
        );
        assert_eq!(at(&d), (3, f.goal_pixel));
        assert_eq!(d.predicted_q, 1.0);
    }
    let config = PolicyConfig {
        max_pushes: 2,
        ..PolicyConfig::default()
    };
    let d = greedy_with(
        &config,
        Mode::PushGrasp,
        &input(&f.obs, &grasp, Some(&f.push), 2),
    );
    assert_eq!(d.reason, Reason::PushBudgetSpent);
}

#[test]
fn grasp_only_mode_and_missing_push_maps_always_grasp() {
    let f = Fixture::new();
    let grasp = f.grasp(0.2);
    let config = PolicyConfig::default();
    for epsilon in [0.0, 1.0] {
        for seed in 0..20 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let i = input(&f.obs, &grasp, Some(&f.push), 0);
            let d = choose(&config, Mode::GraspOnly, &i, epsilon, &mut rng).unwrap();
            assert_eq!(
                (d.action.primitive, d.reason),
                (Primitive::Grasp, Reason::GraspOnlyMode)
            );
        }
    }
    let d = greedy(&input(&f.obs, &grasp, None, 0));
    assert_eq!(
        (d.action.primitive, d.reason),
        (Primitive::Grasp, Reason::NoPushMaps)
    );
    assert_eq!(at(&d), (3, f.goal_pixel));
}

#[test]
fn a_grasp_that_picked_nothing_is_not_made_again_nor_its_near_twins() {
    let obs = scene();
    let centre = pixel(&obs, 0.0, 0.0);
    let (near, far) = ((centre.0, centre.1 + 2), (centre.0 + 4, centre.1));
    // The best grasp, a twin 8 mm beside it and the same grasp the other way along the jaw
    // line (rotation 3 + 8), then one 16 mm away, then one at a rotation 2 turns off.
    let grasp = maps(
        &obs,
        0.0,
        &[
            (3, centre, 2.5),
            (4, near, 2.4),
            (11, centre, 2.35),
            (3, far, 2.2),
            (5, centre, 2.1),
        ],
    );
    let failed = |actions: &[(u8, (usize, usize))]| -> Vec<Action> {
        actions
            .iter()
            .map(|&(rotation, (row, col))| Action {
                primitive: Primitive::Grasp,
                rotation,
                row,
                col,
            })
            .collect()
    };
    let choose_after = |failed: &[Action]| {
        let input = PolicyInput {
            failed_grasps: failed,
            grasp_failed_since_push: false,
            ..input(&obs, &grasp, None, 0)
        };
        greedy_with(&PolicyConfig::default(), Mode::GraspOnly, &input)
    };
    assert_eq!(at(&choose_after(&[])), (3, centre));
    let d = choose_after(&failed(&[(3, centre)]));
    assert_eq!(at(&d), (3, far));
    // The goal's grasp Q the rule compares with Q* is the best grasp still open.
    assert_eq!(d.goal_grasp_q, 2.2);
    assert_eq!(
        at(&choose_after(&failed(&[(3, centre), (3, far)]))),
        (5, centre)
    );
    // Where every grasp of the goal has failed, the region is as it was.
    let side = obs.side();
    let everywhere: Vec<(u8, (usize, usize))> = (0..side * side)
        .filter(|&i| obs.ids[i] == GOAL)
        .flat_map(|i| (0..ROTATIONS).map(move |r| (r, (i / side, i % side))))
        .collect();
    assert_eq!(at(&choose_after(&failed(&everywhere))), (3, centre));
}

#[test]
fn a_grasp_margin_keeps_grasps_off_the_goal_s_rim_and_the_argmax_follows() {
    let obs = scene();
    let mask = obs.goal_mask(GOAL);
    let side = obs.side();
    let on = |region: &[bool]| region.iter().filter(|&&a| a).count();
    // Rows and columns the mask spans: a 5 cm cube is 12 or 13 pixels of 4 mm across.
    let span = |region: &[bool], of: fn(usize, usize) -> usize| {
        let picked: HashSet<usize> = (0..region.len())
            .filter(|&i| region[i])
            .map(|i| of(i, side))
            .collect();
        picked.len()
    };
    let (rows, cols) = (span(&mask, |i, s| i / s), span(&mask, |i, s| i % s));
    assert_eq!(grasp_region(&obs, GOAL, 0.0), mask);
    // One pixel off every side, two pixels: the mask less its rim, all inside the mask.
    for (margin, lost) in [(0.004, 2), (0.009, 4)] {
        let region = grasp_region(&obs, GOAL, margin);
        assert!(region.iter().zip(&mask).all(|(&r, &m)| !r || m));
        assert_eq!(span(&region, |i, s| i / s), rows - lost, "margin {margin}");
        assert_eq!(span(&region, |i, s| i % s), cols - lost, "margin {margin}");
        assert_eq!(on(&region), (rows - lost) * (cols - lost));
    }
    // A rim wider than half the mask leaves its deepest pixels.
    let deepest = grasp_region(&obs, GOAL, 1.0);
    assert!((1..=4).contains(&on(&deepest)), "{}", on(&deepest));
    assert!(deepest.iter().zip(&mask).all(|(&r, &m)| !r || m));

    // The best grasp Q at the rim is passed over for the best inside the margin.
    let (row, col) = (0..mask.len())
        .filter(|&i| mask[i])
        .map(|i| (i / side, i % side))
        .min()
        .unwrap();
    let centre = pixel(&obs, 0.0, 0.0);
    let grasp = maps(&obs, 0.0, &[(3, (row, col), 1.95), (5, centre, 1.9)]);
    let config = PolicyConfig {
        grasp_margin: 0.004,
        ..PolicyConfig::default()
    };
    let d = greedy_with(&config, Mode::GraspOnly, &input(&obs, &grasp, None, 0));
    assert_eq!(at(&d), (5, centre));
    assert_eq!(d.goal_grasp_q, 1.9);
}

#[test]
fn a_hidden_goal_is_scored_over_every_object_and_a_bare_table_over_everything() {
    let mut tabletop = Tabletop::new(&SimConfig::with_pixel_size(PIXEL_SIZE)).unwrap();
    cube(&mut tabletop, GOAL, 0.0, 0.0, 0.025);
    cube(&mut tabletop, 5, 0.0, 0.0, 0.075); // on top of the goal, hiding it
    cube(&mut tabletop, 2, 0.1, 0.0, 0.025);
    let obs = Camera::new(tabletop.grid()).render(&tabletop);
    assert!(!obs.goal_mask(GOAL).contains(&true));
    let region = grasp_region(&obs, GOAL, 0.0);
    assert_eq!(
        region,
        obs.ids.iter().map(|&id| id != 0).collect::<Vec<_>>()
    );

    let top = pixel(&obs, 0.0, 0.0);
    let grasp = maps(
        &obs,
        0.0,
        &[
            (2, top, 1.9),
            (4, pixel(&obs, 0.1, 0.0), 1.5),
            (6, pixel(&obs, 0.17, 0.17), 9.0),
        ],
    );
    let d = greedy(&input(&obs, &grasp, None, 0));
    assert_eq!(at(&d), (2, top));
    assert_eq!(
        (d.reason, d.goal_grasp_q, d.goal_visible),
        (Reason::AboveThreshold, 1.9, false)
    );

    let bare = Heightmaps::new(PixelGrid::new(PIXEL_SIZE).unwrap());
    assert!(grasp_region(&bare, GOAL, 0.0).iter().all(|&a| a));
    let table = (5, 7);
    let grasp = maps(&bare, 0.0, &[(1, table, 0.5)]);
    let d = greedy(&input(&bare, &grasp, None, 0));
    assert_eq!((at(&d), d.goal_grasp_q), ((1, table), 0.5));
}

#[test]
fn push_starts_exclude_object_tops_unless_nothing_else_is_left() {
    let obs = scene();
    let starts = valid_push_starts(&obs);
    let on_objects = obs.ids.iter().filter(|&&id| id != 0).count();
    assert!(
        on_objects > 4 * 100,
        "four 5 cm cubes at 4 mm cover over 400 pixels"
    );
    assert_eq!(starts.iter().filter(|&&s| !s).count(), on_objects);
    for (i, &s) in starts.iter().enumerate() {
        assert_eq!(s, obs.height[i] < PUSH_START_MAX_HEIGHT, "pixel {i}");
    }

    let mut covered = Heightmaps::new(PixelGrid::new(PIXEL_SIZE).unwrap());
    covered.height.fill(0.05);
    covered.ids.fill(GOAL);
    assert!(valid_push_starts(&covered).iter().all(|&s| s));
}

#[test]
fn pushes_never_start_on_an_object_greedy_or_exploring() {
    let obs = scene();
    let config = PolicyConfig::default();
    let goal_mask = obs.goal_mask(GOAL);
    let mut explored_rotations = HashSet::new();
    let mut explored_pixels = HashSet::new();
    for seed in 0..150 {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // Grasp Q below Q* everywhere so the policy pushes; push Q highest anywhere.
        let grasp = random_maps(&obs, -1.0..1.0, &mut rng);
        let push = random_maps(&obs, -1.0..1.0, &mut rng);
        for epsilon in [0.0, 1.0] {
            let i = input(&obs, &grasp, Some(&push), 0);
            let d = choose(&config, Mode::PushGrasp, &i, epsilon, &mut rng).unwrap();
            let a = d.action;
            assert_eq!((a.primitive, d.explored), (Primitive::Push, epsilon == 1.0));
            let h = obs.height[obs.index(a.row, a.col)];
            assert!(
                h < PUSH_START_MAX_HEIGHT,
                "seed {seed}: push starts at height {h}"
            );
            assert_eq!(d.predicted_q, push.get(a.rotation, a.row, a.col));
            if d.explored {
                explored_rotations.insert(a.rotation);
                explored_pixels.insert((a.row, a.col));
            }
        }
        // Exploring grasps stay on the goal.
        let i = input(&obs, &grasp, None, 0);
        let d = choose(&config, Mode::GraspOnly, &i, 1.0, &mut rng).unwrap();
        assert!(
            goal_mask[obs.index(d.action.row, d.action.col)],
            "seed {seed}"
        );
        assert_eq!(
            d.predicted_q,
            grasp.get(d.action.rotation, d.action.row, d.action.col)
        );
    }
    // Exploration spreads over rotations and pixels.
    assert_eq!(explored_rotations.len(), ROTATIONS as usize);
    assert!(
        explored_pixels.len() > 140,
        "{} distinct pixels",
        explored_pixels.len()
    );
}

#[test]
fn trial_grasps_spread_over_the_goal_each_with_its_own_q() {
    let obs = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let grasp = random_maps(&obs, 0.0..2.0, &mut rng);
    let chosen = greedy(&input(&obs, &grasp, None, 0));
    let trials = trial_grasps(
        &obs,
        GOAL,
        &grasp,
        &chosen,
        400,
        &PolicyConfig::default(),
        &mut rng,
    )
    .unwrap();
    assert_eq!(trials.len(), 400);
    let goal = obs.goal_mask(GOAL);
    let side = obs.side();
    for trial in &trials {
        let a = trial.action;
        assert_eq!(a.primitive, Primitive::Grasp);
        assert!(goal[a.row * side + a.col], "{a:?} is off the goal");
        assert_eq!(trial.predicted_q, grasp.get(a.rotation, a.row, a.col));
        assert_eq!(
            (trial.reason, trial.explored, trial.goal_grasp_q),
            (Reason::Trial, true, chosen.goal_grasp_q)
        );
    }
    let rotations: HashSet<u8> = trials.iter().map(|t| t.action.rotation).collect();
    let pixels: HashSet<(usize, usize)> = trials
        .iter()
        .map(|t| (t.action.row, t.action.col))
        .collect();
    assert_eq!(rotations.len(), ROTATIONS as usize);
    let goal_pixels = goal.iter().filter(|&&g| g).count();
    assert!(
        pixels.len() * 2 > goal_pixels,
        "{} of the goal's {goal_pixels} pixels drawn",
        pixels.len()
    );
}

#[test]
fn the_exploration_rate_matches_epsilon() {
    let f = Fixture::new();
    let grasp = f.grasp(1.0);
    let config = PolicyConfig::default();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (draws, epsilon) = (2000, 0.3f32);
    let explored = (0..draws)
        .filter(|_| {
            let i = input(&f.obs, &grasp, Some(&f.push), 0);
            choose(&config, Mode::PushGrasp, &i, epsilon, &mut rng)
                .unwrap()
                .explored
        })
        .count();
    let mean = draws as f32 * epsilon;
    let sigma = (draws as f32 * epsilon * (1.0 - epsilon)).sqrt();
    assert!(
        (explored as f32 - mean).abs() < 3.0 * sigma,
        "{explored} explored of {draws}, expected {mean} +- {sigma}"
    );
}

#[test]
fn epsilon_starts_at_one_half_decays_per_action_and_floors_at_one_tenth() {
    let config = PolicyConfig::default();
    assert_eq!(config.epsilon(0), 0.5);
    assert!((config.epsilon(1) - 0.5 * 0.9998).abs() < 1e-7);
    assert!((config.epsilon(1000) - 0.5 * 0.9998f64.powi(1000) as f32).abs() < 1e-6);
    let mut previous = f32::INFINITY;
    for iteration in (0..20_000).step_by(250) {
        let e = config.epsilon(iteration);
        assert!(e <= previous && e >= 0.1, "iteration {iteration}: {e}");
        previous = e;
    }
    // 0.5 * 0.9998^n reaches 0.1 near n = 8047.
    assert!(config.epsilon(8000) > 0.1);
    assert_eq!(config.epsilon(8100), 0.1);
    assert_eq!(config.epsilon(u64::MAX), 0.1);
}

#[test]
fn the_config_defaults_to_the_papers_numbers_and_refuses_unknown_fields() {
    let config = PolicyConfig::default();
    assert_eq!(
        (
            config.q_star,
            config.max_pushes,
            config.epsilon_start,
            config.epsilon_end
        ),
        (1.8, 5, 0.5, 0.1)
    );
    assert_eq!(config.epsilon_decay, 0.9998);
    let partial: PolicyConfig = toml::from_str("q_star = 1.5").unwrap();
    assert_eq!(
        partial,
        PolicyConfig {
            q_star: 1.5,
            ..PolicyConfig::default()
        }
    );
    let round_trip: PolicyConfig = toml::from_str(&toml::to_string(&config).unwrap()).unwrap();
    assert_eq!(round_trip, config);
    assert!(toml::from_str::<PolicyConfig>("q_starr = 1.5").is_err());
}

#[test]
fn the_same_seed_gives_the_same_decisions() {
    let obs = scene();
    let config = PolicyConfig::default();
    let run = |seed: u64| -> Vec<Decision> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let grasp = random_maps(&obs, 0.0..2.5, &mut rng);
        let push = random_maps(&obs, -1.0..1.0, &mut rng);
        (0..40)
            .map(|k| {
                let i = input(&obs, &grasp, Some(&push), k % 7);
                choose(&config, Mode::PushGrasp, &i, 0.5, &mut rng).unwrap()
            })
            .collect()
    };
    let first = run(7);
    assert_eq!(first, run(7));
    assert_ne!(first, run(8));
    assert!(first.iter().any(|d| d.explored) && first.iter().any(|d| !d.explored));
}

#[test]
fn mismatched_maps_nan_maps_and_bad_epsilons_are_errors() {
    let f = Fixture::new();
    let grasp = f.grasp(1.0);
    let config = PolicyConfig::default();
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut try_choose = |grasp: &QMaps, push: Option<&QMaps>, epsilon: f32| {
        choose(
            &config,
            Mode::PushGrasp,
            &input(&f.obs, grasp, push, 0),
            epsilon,
            &mut rng,
        )
    };

    let small = QMaps::new(ROTATIONS, 56, vec![0.0; ROTATIONS as usize * 56 * 56]).unwrap();
    let side = f.obs.side();
    let eight = QMaps::new(8, side, vec![0.0; 8 * side * side]).unwrap();
    for (g, p, want) in [
        (&small, Some(&f.push), Primitive::Grasp),
        (&grasp, Some(&small), Primitive::Push),
        (&eight, None, Primitive::Grasp),
    ] {
        match try_choose(g, p, 0.0) {
            Err(PolicyError::QMapsShape { primitive, .. }) => assert_eq!(primitive, want),
            other => panic!("{other:?}"),
        }
    }

    let nan = maps(&f.obs, f32::NAN, &[]);
    assert!(matches!(
        try_choose(&nan, Some(&f.push), 0.0),
        Err(PolicyError::NoQValue(Primitive::Grasp))
    ));
    // NaN push Q is reported even when the push would have been explored.
    assert!(matches!(
        try_choose(&grasp, Some(&nan), 1.0),
        Err(PolicyError::NoQValue(Primitive::Push))
    ));
    for epsilon in [-0.1, 1.5, f32::NAN] {
        assert!(matches!(
            try_choose(&grasp, Some(&f.push), epsilon),
            Err(PolicyError::Epsilon(_))
        ));
    }
}

#[test]
fn free_border_grasps_a_goal_with_nothing_around_it_below_q_star() {
    let free = PolicyConfig {
        free_border: Some(0.02),
        ..PolicyConfig::default()
    };
    // The fixture's neighbours stand 10 cm off: the goal's ring is free.
    let f = Fixture::new();
    assert_eq!(sim::measure::occupancy_ratio(&f.obs, GOAL), 0.0);
    let grasp = f.grasp(1.5);
    let decide = |config: &PolicyConfig, mode: Mode| {
        let d = greedy_with(config, mode, &input(&f.obs, &grasp, Some(&f.push), 0));
        (d.action.primitive, d.reason)
    };
    assert_eq!(
        decide(&PolicyConfig::default(), Mode::PushGrasp),
        (Primitive::Push, Reason::BelowThreshold)
    );
    assert_eq!(
        decide(&free, Mode::PushGrasp),
        (Primitive::Grasp, Reason::BorderFree)
    );
    assert_eq!(
        decide(&free, Mode::GraspOnly),
        (Primitive::Grasp, Reason::GraspOnlyMode)
    );
    // VPG's rule compares Q values alone: a push Q of 1.0 above a grasp Q of 0.5 pushes.
    let vpg = PolicyConfig {
        rule: Rule::HigherQ,
        ..free.clone()
    };
    let low = f.grasp(0.5);
    let d = greedy_with(
        &vpg,
        Mode::PushGrasp,
        &input(&f.obs, &low, Some(&f.push), 0),
    );
    assert_eq!(
        (d.action.primitive, d.reason),
        (Primitive::Push, Reason::PushQHigher)
    );

    // A goal with a crowded ring is pushed as without the setting.
    let crowded = crowded_scene();
    let grasp = maps(&crowded, 0.0, &[(3, pixel(&crowded, 0.0, 0.0), 1.5)]);
    let push = maps(&crowded, 0.0, &[(7, pixel(&crowded, 0.0, -0.1), 1.0)]);
    let d = greedy_with(
        &free,
        Mode::PushGrasp,
        &input(&crowded, &grasp, Some(&push), 0),
    );
    assert_eq!(
        (d.action.primitive, d.reason),
        (Primitive::Push, Reason::BelowThreshold)
    );
}

#[test]
fn free_border_once_pushes_a_free_goal_whose_grasp_has_failed_since_the_last_push() {
    let f = Fixture::new();
    let grasp = f.grasp(1.5);
    let decide = |config: &PolicyConfig, grasp_failed_since_push: bool| {
        let input = PolicyInput {
            grasp_failed_since_push,
            ..input(&f.obs, &grasp, Some(&f.push), 0)
        };
        let d = greedy_with(config, Mode::PushGrasp, &input);
        (d.action.primitive, d.reason)
    };
    let free = PolicyConfig {
        free_border: Some(0.02),
        ..PolicyConfig::default()
    };
    let once = PolicyConfig {
        free_border_once: true,
        ..free.clone()
    };
    let grasps = (Primitive::Grasp, Reason::BorderFree);
    let pushes = (Primitive::Push, Reason::BelowThreshold);
    assert_eq!(decide(&free, true), grasps);
    assert_eq!(decide(&once, false), grasps);
    assert_eq!(decide(&once, true), pushes);
    // Above Q* it grasps whatever failed before.
    let sure = f.grasp(2.5);
    let input = PolicyInput {
        grasp_failed_since_push: true,
        ..input(&f.obs, &sure, Some(&f.push), 0)
    };
    assert_eq!(
        greedy_with(&once, Mode::PushGrasp, &input).reason,
        Reason::AboveThreshold
    );
}
