//! What an actor shows of a step in its MCAP log: the heightmaps, the best Q maps and the
//! scene, for Foxglove.

use anyhow::Result;
use mcaplog::RunLog;
use policy::QMaps;
use sim::{Heightmaps, Tabletop};

use rundir::record::{ACTOR_COLOUR, ACTOR_GRASP_Q, ACTOR_HEIGHT, ACTOR_PUSH_Q, ACTOR_SCENE};

/// What the actor saw and the scene it acted on, all at one time, which is returned: colour,
/// height (tenths of a millimetre) and the best grasp and push Q over the rotations
/// (hundredths, so 0..2.55) as images Foxglove shows as they are, and the objects as boxes.
pub(super) fn log_pictures(
    log: &RunLog,
    tabletop: &Tabletop,
    obs: &Heightmaps,
    grasp: &QMaps,
    push: Option<&QMaps>,
) -> Result<u64> {
    let t = mcaplog::now_ns();
    if !log.enabled() {
        return Ok(t);
    }
    let side = obs.side() as u32;
    let colour: Vec<u8> = obs.colour.iter().flatten().copied().collect();
    let height: Vec<u8> = obs
        .height
        .iter()
        .flat_map(|h| ((h * 1e4).round().clamp(0.0, 65535.0) as u16).to_le_bytes())
        .collect();
    log.raw_image(ACTOR_COLOUR, t, side, side, "rgb8", &colour)?;
    log.raw_image(ACTOR_HEIGHT, t, side, side, "mono16", &height)?;
    log.raw_image(ACTOR_GRASP_Q, t, side, side, "mono8", &best_q(grasp))?;
    if let Some(push) = push {
        log.raw_image(ACTOR_PUSH_Q, t, side, side, "mono8", &best_q(push))?;
    }
    log.scene_update(ACTOR_SCENE, t, &scene_update(tabletop, t))?;
    Ok(t)
}

/// The best Q over the rotations per pixel, in hundredths.
fn best_q(maps: &QMaps) -> Vec<u8> {
    let side = maps.side();
    (0..side * side)
        .map(|i| {
            let best = (0..maps.rotations())
                .map(|k| maps.get(k, i / side, i % side))
                .fold(f32::NEG_INFINITY, f32::max);
            (best * 100.0).round().clamp(0.0, 255.0) as u8
        })
        .collect()
}

/// The objects on the table as boxes in the world frame, one entity per object id.
fn scene_update(tabletop: &Tabletop, time_ns: u64) -> mcaplog::SceneUpdate {
    let vector = |v: sim::rapier3d::prelude::Vector| mcaplog::Vector3 {
        x: f64::from(v.x),
        y: f64::from(v.y),
        z: f64::from(v.z),
    };
    let entities = tabletop
        .objects()
        .map(|object| {
            let (lo, hi) = object.kind.bounds();
            let q = object.pose.rotation;
            let [r, g, b] = object.colour.map(|c| f64::from(c) / 255.0);
            mcaplog::SceneEntity {
                timestamp: Some(mcaplog::timestamp(time_ns)),
                frame_id: "world".into(),
                id: format!("object-{}", object.id),
                lifetime: None,
                frame_locked: false,
                cubes: vec![mcaplog::CubePrimitive {
                    pose: Some(mcaplog::Pose {
                        position: Some(vector(object.pose.transform_point((lo + hi) / 2.0))),
                        orientation: Some(mcaplog::Quaternion {
                            x: f64::from(q.x),
                            y: f64::from(q.y),
                            z: f64::from(q.z),
                            w: f64::from(q.w),
                        }),
                    }),
                    size: Some(vector(hi - lo)),
                    color: Some(mcaplog::Color { r, g, b, a: 1.0 }),
                }],
            }
        })
        .collect();
    mcaplog::SceneUpdate { entities }
}
