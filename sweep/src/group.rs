//! Runs that differ only in their seed, grouped so their figures can be summarised.

use crate::expand::{RunPlan, label};

/// Groups runs whose overrides agree on every key but `key` (e.g. `"seed"`): each group's
/// label (the other overrides as in [`RunPlan::label`]; empty when there are none) and its
/// runs' indices, groups in order of their first run.
pub fn group_by_all_but(runs: &[RunPlan], key: &str) -> Vec<(String, Vec<usize>)> {
    let mut groups: Vec<(String, Vec<usize>)> = Vec::new();
    for run in runs {
        let others = label(
            run.overrides
                .iter()
                .filter(|(k, _)| k != key)
                .map(|(k, value)| (k.as_str(), value)),
        );
        match groups.iter_mut().find(|(label, _)| *label == others) {
            Some((_, indices)) => indices.push(run.index),
            None => groups.push((others, vec![run.index])),
        }
    }
    groups
}
