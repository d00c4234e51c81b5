//! A grasp net scored against the outcomes of the goal's grasps: how well its Q ranks the
//! grasps that always pick the goal above those that never do, and how its best fare.

use agent::Agent;
use anyhow::Result;
use qnet::NetInput;
use serde::Serialize;
use sim::{Action, Heightmaps, ObjectId, Primitive, ROTATIONS};

/// A grasp net's Q on the goal's grasps against their outcomes.
#[derive(Debug, Serialize)]
pub(super) struct NetScore {
    /// The chance that a grasp that always picks the goal has a higher Q than one that
    /// never does (0.5: the Q does not tell them apart; ties count half); absent when
    /// either kind is missing.
    pub(super) net_auc: Option<f64>,
    /// Share of tries of the grasp with the highest Q that picked the goal.
    pub(super) net_best: f64,
    /// The same over the [`TOP_K`] grasps with the highest Q.
    pub(super) net_top_k: f64,
}

/// How many of the grasps the net scores highest `net_top_k` tries.
pub(super) const TOP_K: usize = 5;

/// The grasp net's Q for each candidate on `maps` (the better of its two jaw angles, k and
/// k + 8, which are the same grasp) against how many of `jitters` tries picked the goal.
pub(super) fn score_net(
    agent: &Agent,
    maps: &Heightmaps,
    goal: ObjectId,
    candidates: &[Action],
    picks: &[usize],
    jitters: usize,
) -> Result<NetScore> {
    let q_maps = agent.q_maps(Primitive::Grasp, &NetInput::encode(maps, goal))?;
    let q: Vec<f32> = candidates
        .iter()
        .map(|a| {
            let opposite = a.rotation + ROTATIONS / 2;
            q_maps
                .get(a.rotation, a.row, a.col)
                .max(q_maps.get(opposite, a.row, a.col))
        })
        .collect();
    let with = |n: usize| -> Vec<f32> {
        q.iter()
            .zip(picks)
            .filter(|(_, p)| **p == n)
            .map(|(q, _)| *q)
            .collect()
    };
    let mut ranked: Vec<usize> = (0..q.len()).collect();
    ranked.sort_by(|&i, &j| q[j].total_cmp(&q[i]));
    let success = |grasps: &[usize]| {
        grasps.iter().map(|&i| picks[i]).sum::<usize>() as f64 / (grasps.len() * jitters) as f64
    };
    Ok(NetScore {
        net_auc: auc(&with(jitters), &with(0)),
        net_best: success(&ranked[..1]),
        net_top_k: success(&ranked[..TOP_K.min(ranked.len())]),
    })
}

/// The chance that a value drawn from `higher` exceeds one drawn from `lower`, ties
/// counting half (the area under the ROC curve); `None` when either is empty.
fn auc(higher: &[f32], lower: &[f32]) -> Option<f64> {
    let pairs = (higher.len() * lower.len()) as f64;
    let wins: f64 = higher
        .iter()
        .flat_map(|h| {
            lower.iter().map(move |l| match h.total_cmp(l) {
                std::cmp::Ordering::Greater => 1.0,
                std::cmp::Ordering::Equal => 0.5,
                std::cmp::Ordering::Less => 0.0,
            })
        })
        .sum();
    (pairs > 0.0).then(|| wins / pairs)
}

#[cfg(test)]
mod tests {
    use super::auc;

    #[test]
    fn auc_is_the_share_of_pairs_ranked_right() {
        assert_eq!(auc(&[2.0, 3.0], &[0.0, 1.0]), Some(1.0));
        assert_eq!(auc(&[0.0, 1.0], &[2.0, 3.0]), Some(0.0));
        assert_eq!(auc(&[1.0], &[1.0]), Some(0.5));
        // 2 > 1, 2 < 3; 0 < 1, 0 < 3: one pair of four.
        assert_eq!(auc(&[2.0, 0.0], &[1.0, 3.0]), Some(0.25));
        assert_eq!(auc(&[], &[1.0]), None);
    }
}
