//! Mean and spread against hand-computed figures.

use stats::mean_and_spread;

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-12
}

#[test]
fn mean_and_sample_standard_deviation() {
    let (mean, spread) = mean_and_spread(&[2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0]).unwrap();
    assert!(close(mean, 5.0));
    // Sample (n - 1) deviation: sqrt(32 / 7), not the population's 2.
    assert!(close(spread, (32.0f64 / 7.0).sqrt()), "{spread}");

    let (mean, spread) = mean_and_spread(&[0.83, 0.85, 0.70]).unwrap();
    assert!(close(mean, 0.7933333333333333), "{mean}");
    // Python: statistics.stdev([0.83, 0.85, 0.70]).
    assert!(close(spread, 0.08144527815247078), "{spread}");
}

#[test]
fn one_value_has_no_spread_and_none_has_no_mean() {
    assert_eq!(mean_and_spread(&[0.7]), Some((0.7, 0.0)));
    assert_eq!(mean_and_spread(&[]), None);
}
