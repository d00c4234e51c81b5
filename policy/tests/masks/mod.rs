//! Helpers of the push masks' tests (the goal guard, the push reach): a scene of cubes, a
//! push from a point, and the policy's choice when one push has the highest Q.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sim::workspace::CENTRE;
use sim::{Action, Camera, Heightmaps, ObjectId, Primitive, ROTATIONS, SimConfig, Tabletop};

use policy::{Mode, PolicyConfig, PolicyInput, QMaps, choose};

use crate::common::cube;

/// 5 cm cubes resting on the table, each (id, dx, dy) offset from the workspace centre, at
/// 4 mm pixels; the scene, what the camera sees, and its config.
pub fn cubes(at: &[(ObjectId, f32, f32)]) -> (Tabletop, Heightmaps, SimConfig) {
    let config = SimConfig::with_pixel_size(0.004);
    let mut tabletop = Tabletop::new(&config).unwrap();
    for &(id, dx, dy) in at {
        cube(&mut tabletop, id, dx, dy, 0.025);
    }
    let obs = Camera::new(tabletop.grid()).render(&tabletop);
    (tabletop, obs, config)
}

/// A push at `rotation` from the point offset (dx, dy) from the workspace centre.
pub fn push(obs: &Heightmaps, rotation: u8, dx: f32, dy: f32) -> Action {
    let (row, col) = obs.grid.pixel_of(CENTRE[0] + dx, CENTRE[1] + dy).unwrap();
    Action {
        primitive: Primitive::Push,
        rotation,
        row,
        col,
    }
}

/// Where `action` lies in a mask laid out [rotation][row][col].
pub fn index(obs: &Heightmaps, action: &Action) -> usize {
    let side = obs.side();
    (action.rotation as usize * side + action.row) * side + action.col
}

/// What `policy` does for `goal` when `peak` is the one push with a Q above 0 and every
/// grasp's Q is 0 (below Q*: a push is due), exploring with `epsilon` from `seed`, the
/// landing guard reading `landing_view` where given.
#[allow(clippy::too_many_arguments)]
pub fn chosen(
    obs: &Heightmaps,
    landing_view: Option<&Heightmaps>,
    goal: ObjectId,
    push_length: f32,
    peak: &Action,
    policy: &PolicyConfig,
    epsilon: f32,
    seed: u64,
) -> Action {
    let mut push_q = vec![0.0; ROTATIONS as usize * obs.side() * obs.side()];
    push_q[index(obs, peak)] = 5.0;
    let push_maps = QMaps::new(ROTATIONS, obs.side(), push_q).unwrap();
    let grasp_maps =
        QMaps::new(ROTATIONS, obs.side(), vec![0.0; push_maps.values().len()]).unwrap();
    let input = PolicyInput {
        obs,
        goal,
        grasp: &grasp_maps,
        push: Some(&push_maps),
        pushes_so_far: 0,
        push_length,
        landing_view,
        failed_grasps: &[],
        grasp_failed_since_push: false,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    choose(policy, Mode::PushGrasp, &input, epsilon, &mut rng)
        .unwrap()
        .action
}
