//! Grouping runs over seeds.

use sweep::{Axis, RunPlan, group_by_all_but};
use toml::Value;

fn run(index: usize, overrides: &[(&str, Value)]) -> RunPlan {
    RunPlan {
        index,
        id: format!("s-{index}"),
        overrides: overrides
            .iter()
            .map(|(key, value)| (key.to_string(), value.clone()))
            .collect(),
        config: toml::Table::new(),
    }
}

#[test]
fn groups_runs_that_differ_only_in_the_seed() {
    let lr = |x: f64| ("learning.learning_rate", Value::Float(x));
    let seed = |s: i64| ("seed", Value::Integer(s));
    let runs = [
        run(0, &[lr(0.001), seed(1)]),
        run(1, &[lr(0.001), seed(2)]),
        run(2, &[lr(0.0001), seed(1)]),
        run(3, &[lr(0.0001), seed(2)]),
        run(4, &[lr(0.001), seed(3)]),
    ];
    assert_eq!(
        group_by_all_but(&runs, "seed"),
        [
            ("learning.learning_rate=0.001".to_string(), vec![0, 1, 4]),
            ("learning.learning_rate=0.0001".to_string(), vec![2, 3]),
        ]
    );
}

#[test]
fn grouping_an_expanded_sweep() {
    let sweep = sweep::Sweep {
        path: "s.toml".into(),
        name: "s".to_string(),
        base_path: "base.toml".into(),
        base: toml::Table::new(),
        budget: sweep::Budget::default(),
        axes: vec![
            Axis {
                keys: vec!["seed".to_string()],
                points: (1..=3).map(|s| vec![Value::Integer(s)]).collect(),
            },
            Axis {
                keys: vec!["objects".to_string(), "stage".to_string()],
                points: vec![
                    vec![Value::Integer(5), Value::Integer(1)],
                    vec![Value::Integer(10), Value::Integer(2)],
                ],
            },
        ],
        slurm: sweep::SlurmOptions::default(),
    };
    let groups = group_by_all_but(&sweep.expand(), "seed");
    assert_eq!(
        groups,
        [
            ("objects=5 stage=1".to_string(), vec![0, 2, 4]),
            ("objects=10 stage=2".to_string(), vec![1, 3, 5]),
        ]
    );
    // A sweep over seeds alone is one group with an empty label.
    let seeds_only = sweep::Sweep {
        axes: sweep.axes[..1].to_vec(),
        ..sweep
    };
    assert_eq!(
        group_by_all_but(&seeds_only.expand(), "seed"),
        [(String::new(), vec![0, 1, 2])]
    );
}
