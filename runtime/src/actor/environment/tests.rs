//! The actor's episode rules on a scene built by hand.

use super::*;
use policy::Reason;
use sim::rapier3d::prelude::{Pose, Rotation, Vector};
use sim::workspace::{CENTRE, X_MAX};
use sim::{Action, ShapeKind};

/// Stage 2's config, with no pictures logged.
fn stage2_config() -> RunConfig {
    let mut config = RunConfig::load(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../configs/stage2.toml"
    )))
    .unwrap();
    config.logging.image_every = 0;
    config
}

/// An environment with no episode under way on a scene of lone cubes, `(id, x)` each, at
/// the workspace's middle row, settled.
fn lone_cubes<'a>(
    config: &'a RunConfig,
    log: &'a RunLog,
    cubes: &[(ObjectId, f32)],
) -> Environment<'a> {
    let id = ActorId {
        index: 0,
        incarnation: 0,
    };
    let mut env = Environment::new(config, id, log).unwrap();
    env.tabletop = Tabletop::new(&config.sim).unwrap();
    for &(object, x) in cubes {
        let pose = Pose::from_parts(Vector::new(x, CENTRE[1], 0.025), Rotation::IDENTITY);
        env.tabletop
            .add_object(object, ShapeKind::Cube, [200, 50, 50], pose)
            .unwrap();
    }
    env.tabletop.settle();
    env
}

/// An environment whose episode's goal, a lone cube, lies 3 cm inside the workspace's +x
/// edge.
fn at_the_edge<'a>(config: &'a RunConfig, log: &'a RunLog) -> Environment<'a> {
    let mut env = lone_cubes(config, log, &[(1, X_MAX - 0.03)]);
    let obs = env.camera.render(&env.tabletop);
    env.episode = Some(Episode {
        obs,
        goal: 1,
        step: 0,
    });
    env
}

/// Pushes along +x from 7 cm before the cube to the edge: the closed jaws carry it wholly
/// past the edge, out of view.
fn push_off(env: &mut Environment<'_>) -> Vec<Completed> {
    let grid = env.tabletop.grid();
    let (row, col) = grid.pixel_of(X_MAX - 0.10, CENTRE[1]).unwrap();
    let side = grid.side();
    let choice = Choice {
        decision: Decision {
            action: Action {
                primitive: Primitive::Push,
                rotation: 0,
                row,
                col,
            },
            predicted_q: 0.0,
            goal_grasp_q: 0.5,
            best_push_q: Some(0.0),
            explored: false,
            reason: Reason::BelowThreshold,
            goal_visible: true,
        },
        grasp: QMaps::new(16, side, vec![0.0; 16 * side * side]).unwrap(),
        push: None,
    };
    let completed = env.act(choice, 0).unwrap();
    assert!(
        env.tabletop.object(1).is_none(),
        "the push left the goal in view"
    );
    completed
}

#[test]
fn a_push_that_takes_the_goal_out_of_view_ends_its_episode_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let log = RunLog::create(dir.path().join("actor.mcap"), "actor").unwrap();
    let mut config = stage2_config();

    config.goal_lost_ends_episode = true;
    let mut env = at_the_edge(&config, &log);
    let completed = push_off(&mut env);
    let [(push, next)] = completed.as_slice() else {
        panic!("{} steps completed, not the push alone", completed.len());
    };
    assert!(
        next.is_none(),
        "a push that lost the goal bootstraps on nothing"
    );
    let end = push.ends.as_ref().expect("the push ends its episode");
    assert_eq!((end.grasped, end.steps, end.trial), (None, 1, false));
    assert!(!push.push_changed.as_ref().unwrap().detected);
    assert!(env.episode.is_none() && env.unlabelled.is_none());
    assert_eq!(env.report.episodes, 1);

    config.goal_lost_ends_episode = false;
    let mut env = at_the_edge(&config, &log);
    assert!(push_off(&mut env).is_empty());
    assert_eq!(env.episode.as_ref().map(|e| (e.goal, e.step)), Some((1, 1)));
    assert!(env.unlabelled.as_ref().is_some_and(|p| p.ends.is_none()));
    assert_eq!(env.report.episodes, 0);
}

#[test]
fn goals_over_the_workspace_leave_out_an_object_past_its_edge() {
    let dir = tempfile::tempdir().unwrap();
    let log = RunLog::create(dir.path().join("actor.mcap"), "actor").unwrap();
    let mut config = stage2_config();
    // Every goal the most crowded: of two lone cubes, the higher id, the one past the edge.
    config.crowded_goals = 1.0;
    for (over_workspace, goal) in [(false, 2), (true, 1)] {
        config.goals_over_workspace = over_workspace;
        let mut env = lone_cubes(&config, &log, &[(1, CENTRE[0]), (2, X_MAX + 0.01)]);
        assert_eq!(env.camera.render(&env.tabletop).visible_ids(), vec![1, 2]);
        env.episode_start().unwrap();
        assert_eq!(env.episode.as_ref().map(|e| e.goal), Some(goal));
    }

    // With only the cube past the edge left, there is no goal to take: a new scene.
    let mut env = lone_cubes(&config, &log, &[(2, X_MAX + 0.01)]);
    let seed = env.scene_seed;
    env.episode_start().unwrap();
    assert_eq!(env.scene_seed, seed + 1);
    let goal = env.episode.as_ref().expect("a goal in the new scene").goal;
    let centre = env.tabletop.object(goal).unwrap().pose.translation;
    assert!(workspace::contains(centre.x, centre.y));
}

#[test]
fn a_goal_per_scene_is_taken_again_until_it_leaves_and_then_the_scene_is_new() {
    let dir = tempfile::tempdir().unwrap();
    let log = RunLog::create(dir.path().join("actor.mcap"), "actor").unwrap();
    let mut config = stage2_config();
    let cubes = [(1, CENTRE[0] - 0.1), (2, CENTRE[0]), (3, CENTRE[0] + 0.1)];
    // Episodes that end without taking anything, as failed grasps do: their goals.
    let goals = |env: &mut Environment<'_>| -> Vec<ObjectId> {
        (0..12)
            .map(|_| {
                env.episode_start().unwrap();
                env.episode.take().expect("a goal among three cubes").goal
            })
            .collect()
    };

    config.goal_per_scene = false;
    let mut env = lone_cubes(&config, &log, &cubes);
    let drawn = goals(&mut env);
    assert!(
        drawn.iter().any(|&g| g != drawn[0]),
        "one goal drawn: {drawn:?}"
    );

    config.goal_per_scene = true;
    let mut env = lone_cubes(&config, &log, &cubes);
    let seed = env.scene_seed;
    let kept = goals(&mut env);
    assert!(kept.iter().all(|&g| g == kept[0]), "goals {kept:?}");
    assert_eq!(
        env.scene_seed, seed,
        "a scene dropped while its goal was seen"
    );

    // The goal leaves (grasped, or pushed out of view), two cubes still seen: a new scene.
    assert!(env.tabletop.remove_object(kept[0]));
    env.episode_start().unwrap();
    assert_eq!(env.scene_seed, seed + 1);
    assert_eq!(env.tabletop.object_count(), config.objects);
    assert_eq!(env.scene_goal, env.episode.as_ref().map(|e| e.goal));
}

#[test]
fn a_scene_dropped_anew_for_its_goals_leaving_keeps_the_chain_an_emptied_one_ends_it() {
    let dir = tempfile::tempdir().unwrap();
    let log = RunLog::create(dir.path().join("actor.mcap"), "actor").unwrap();
    let mut config = stage2_config();
    for goal_per_scene in [true, false] {
        config.goal_per_scene = goal_per_scene;
        // The goal, the scene's only object, pushed out of view; the push waits for its
        // next state.
        let mut env = at_the_edge(&config, &log);
        env.scene_goal = Some(1);
        push_off(&mut env);
        env.episode = None;
        let seed = env.scene_seed;
        let chain_end = env.episode_start().unwrap();
        assert_eq!(env.scene_seed, seed + 1, "goal per scene: {goal_per_scene}");
        assert_eq!(chain_end.is_none(), goal_per_scene);
        assert_eq!(env.unlabelled.is_some(), goal_per_scene);
    }
}
