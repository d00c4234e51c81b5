//! Helper of the grasp guards' tests: the policy's choice when one grasp has the highest Q.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sim::{Action, Heightmaps, ObjectId, ROTATIONS};

use policy::{Decision, Mode, PolicyConfig, PolicyInput, QMaps, choose};

/// What `policy` does for `goal` when every grasp's Q is 2.0 (above Q*: a grasp is due) but
/// `peak`'s, 5.0, with no push maps, greedily.
pub fn chosen_grasp(
    obs: &Heightmaps,
    goal: ObjectId,
    peak: &Action,
    policy: &PolicyConfig,
    push_length: f32,
) -> Decision {
    let side = obs.side();
    let mut grasp_q = vec![2.0; ROTATIONS as usize * side * side];
    grasp_q[(peak.rotation as usize * side + peak.row) * side + peak.col] = 5.0;
    let grasp = QMaps::new(ROTATIONS, side, grasp_q).unwrap();
    let input = PolicyInput {
        obs,
        goal,
        grasp: &grasp,
        push: None,
        pushes_so_far: 0,
        push_length,
        landing_view: None,
        failed_grasps: &[],
        grasp_failed_since_push: false,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    choose(policy, Mode::PushGrasp, &input, 0.0, &mut rng).unwrap()
}
