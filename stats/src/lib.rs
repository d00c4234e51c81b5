//! Statistics that the evaluation of one net and the summary of a sweep both report: a
//! figure's mean over runs or seeds, and its spread.

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
