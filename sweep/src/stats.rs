//! Statistics over runs that differ only in their seed.

use crate::expand::{RunPlan, label};

/// The mean and the sample standard deviation (n - 1 in the denominator; 0 for one value),
/// or `None` for no values.
pub fn mean_and_spread(values: &[f64]) -> Option<(f64, f64)> {
    let n = values.len();
    if n == 0 {
        return None;
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    if n == 1 {
        return Some((mean, 0.0));
    }
    let squares: f64 = values.iter().map(|x| (x - mean).powi(2)).sum();
    Some((mean, (squares / (n - 1) as f64).sqrt()))
}

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
