//! Sweep files: loading, every rejection, and expansion into runs.

use std::path::{Path, PathBuf};

use sweep::{Sweep, SweepError, dry_run_listing};
use tempfile::TempDir;
use toml::Value;

const BASE: &str = r#"
stage = 1
seed = 1
actors = 2
episodes = 400

[policy]
epsilon_start = 0.5

[learning]
learning_rate = 1e-3
"#;

/// Writes `base` as `configs/stage1.toml` and `sweep` as `configs/sweeps/test.toml` (whose
/// `base = "../stage1.toml"` finds it); returns the directory and the sweep file's path.
fn write_files(sweep: &str, base: &str) -> (TempDir, PathBuf) {
    let dir = TempDir::new().unwrap();
    let sweeps = dir.path().join("configs").join("sweeps");
    std::fs::create_dir_all(&sweeps).unwrap();
    std::fs::write(dir.path().join("configs").join("stage1.toml"), base).unwrap();
    let path = sweeps.join("test.toml");
    std::fs::write(&path, sweep).unwrap();
    (dir, path)
}

fn load_with_base(sweep: &str, base: &str) -> Result<Sweep, SweepError> {
    let (_dir, path) = write_files(sweep, base);
    Sweep::load(&path)
}

fn load(sweep: &str) -> Sweep {
    load_with_base(sweep, BASE).unwrap()
}

/// The error's message, checked to name the sweep file.
fn load_error(sweep: &str) -> String {
    let (_dir, path) = write_files(sweep, BASE);
    let message = Sweep::load(&path).unwrap_err().to_string();
    assert!(
        message.contains(&path.display().to_string()),
        "{message:?} does not name {}",
        path.display()
    );
    message
}

fn assert_contains(message: &str, parts: &[&str]) {
    for part in parts {
        assert!(message.contains(part), "{message:?} lacks {part:?}");
    }
}

/// The values one key takes over the runs, in run order.
fn column(sweep: &Sweep, key: &str) -> Vec<Value> {
    sweep
        .expand()
        .iter()
        .map(|run| {
            run.overrides
                .iter()
                .find(|(k, _)| k == key)
                .map(|(_, value)| value.clone())
                .unwrap()
        })
        .collect()
}

fn floats(values: &[Value]) -> Vec<f64> {
    values.iter().map(|v| v.as_float().unwrap()).collect()
}

fn lookup<'a>(config: &'a toml::Table, key: &str) -> &'a Value {
    let (last, parents) = key
        .rsplit_once('.')
        .map_or((key, None), |(p, l)| (l, Some(p)));
    let table = parents.map_or(config, |parents| {
        parents
            .split('.')
            .fold(config, |table, part| table[part].as_table().unwrap())
    });
    &table[last]
}

const COMPLETE: &str = r#"
name = "stage1-lr"
base = "../stage1.toml"
budget = { episodes = 200 }

[[axis]]
key = "seed"
values = [1, 2, 3]

[[axis]]
key = "learning.learning_rate"
range = { from = 1e-4, to = 1e-3, steps = 3, scale = "log" }

[[axis]]
key = "policy.epsilon_start"
random = { low = 0.3, high = 0.6, draws = 2, seed = 7, scale = "linear" }

[[axis]]
zip = [ { key = "objects", values = [5, 10] }, { key = "stage", values = [1, 2] } ]

[slurm]
partition = "gpu"
time = "02:00:00"
mem = "8G"
max_parallel = 4
extra = ["--gres=gpu:1"]
"#;

#[test]
fn complete_example_loads() {
    let (dir, path) = write_files(COMPLETE, BASE);
    let sweep = Sweep::load(&path).unwrap();
    assert_eq!(sweep.name, "stage1-lr");
    assert_eq!(sweep.path, path);
    assert_eq!(
        sweep.base_path,
        dir.path()
            .join("configs")
            .join("sweeps")
            .join("../stage1.toml")
    );
    assert_eq!(sweep.budget.episodes, Some(200));
    assert_eq!(sweep.axes.len(), 4);
    assert_eq!(sweep.axes[3].keys, ["objects", "stage"]);
    assert_eq!(sweep.slurm.partition.as_deref(), Some("gpu"));
    assert_eq!(sweep.slurm.extra, ["--gres=gpu:1"]);
    assert_eq!(sweep.run_count(), 3 * 3 * 2 * 2);
    assert_eq!(sweep.expand().len(), 36);
}

#[test]
fn grid_is_a_product_with_the_first_axis_slowest() {
    let sweep = load(
        r#"
        name = "grid"
        base = "../stage1.toml"
        [[axis]]
        key = "seed"
        values = [1, 2, 3]
        [[axis]]
        key = "learning.gamma"
        values = [0.5, 0.9]
        "#,
    );
    let runs = sweep.expand();
    assert_eq!(runs.len(), 6);
    let pairs: Vec<(i64, f64)> = runs
        .iter()
        .map(|run| {
            (
                run.overrides[0].1.as_integer().unwrap(),
                run.overrides[1].1.as_float().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        pairs,
        [(1, 0.5), (1, 0.9), (2, 0.5), (2, 0.9), (3, 0.5), (3, 0.9)]
    );
    assert!(runs.iter().enumerate().all(|(i, run)| run.index == i));
    assert_eq!(runs[3].label(), "seed=2 learning.gamma=0.9");
}

#[test]
fn values_may_be_any_toml_value() {
    let sweep = load(
        r#"
        name = "kinds"
        base = "../stage1.toml"
        [[axis]]
        key = "net.trunk_widths"
        values = [[8, 16], [16, 32]]
        [[axis]]
        key = "mode"
        values = ["push", "grasp"]
        [[axis]]
        key = "record"
        values = [true]
        "#,
    );
    let runs = sweep.expand();
    assert_eq!(runs.len(), 4);
    assert_eq!(
        runs[1].label(),
        r#"net.trunk_widths=[8, 16] mode="grasp" record=true"#
    );
    assert_eq!(
        lookup(&runs[2].config, "net.trunk_widths"),
        &Value::Array(vec![Value::Integer(16), Value::Integer(32)])
    );
}

#[test]
fn zip_moves_its_keys_together() {
    let sweep = load(
        r#"
        name = "zip"
        base = "../stage1.toml"
        [[axis]]
        zip = [ { key = "objects", values = [5, 10] }, { key = "stage", values = [1, 2] } ]
        [[axis]]
        key = "seed"
        values = [1, 2]
        "#,
    );
    let labels: Vec<String> = sweep.expand().iter().map(|run| run.label()).collect();
    assert_eq!(
        labels,
        [
            "objects=5 stage=1 seed=1",
            "objects=5 stage=1 seed=2",
            "objects=10 stage=2 seed=1",
            "objects=10 stage=2 seed=2",
        ]
    );
}

#[test]
fn zip_of_unequal_lengths_is_rejected() {
    let message = load_error(
        r#"
        name = "zip"
        base = "../stage1.toml"
        [[axis]]
        key = "seed"
        values = [1]
        [[axis]]
        zip = [ { key = "objects", values = [5, 10] }, { key = "stage", values = [1, 2, 3] } ]
        "#,
    );
    assert_contains(
        &message,
        &["[[axis]] number 2", "objects, stage", "zip lengths differ"],
    );
}

#[test]
fn log_range_has_exact_ends_and_rounded_interior() {
    let sweep = load(
        r#"
        name = "lr"
        base = "../stage1.toml"
        [[axis]]
        key = "learning.learning_rate"
        range = { from = 1e-4, to = 1e-3, steps = 3, scale = "log" }
        "#,
    );
    let values = column(&sweep, "learning.learning_rate");
    assert_eq!(floats(&values), [0.0001, 0.000316228, 0.001]);
    let runs = sweep.expand();
    assert_eq!(runs[0].label(), "learning.learning_rate=0.0001");
    assert_eq!(runs[2].label(), "learning.learning_rate=0.001");
    assert_eq!(
        lookup(&runs[1].config, "learning.learning_rate"),
        &Value::Float(0.000316228)
    );
}

#[test]
fn linear_range_lands_on_round_numbers() {
    let sweep = load(
        r#"
        name = "gamma"
        base = "../stage1.toml"
        [[axis]]
        key = "learning.gamma"
        range = { from = 0.1, to = 0.5, steps = 5 }
        "#,
    );
    assert_eq!(
        floats(&column(&sweep, "learning.gamma")),
        [0.1, 0.2, 0.3, 0.4, 0.5]
    );
}

#[test]
fn close_range_points_keep_enough_digits_to_differ() {
    let sweep = load(
        r#"
        name = "close"
        base = "../stage1.toml"
        [[axis]]
        key = "learning.gamma"
        range = { from = 0.5, to = 0.5000001, steps = 4 }
        "#,
    );
    let values = floats(&column(&sweep, "learning.gamma"));
    assert!(
        values.windows(2).all(|pair| pair[0] < pair[1]),
        "{values:?}"
    );
}

#[test]
fn integer_range_gives_integers() {
    let sweep = load(
        r#"
        name = "batch"
        base = "../stage1.toml"
        [[axis]]
        key = "replay.batch"
        range = { from = 8, to = 256, steps = 6, scale = "log", integer = true }
        "#,
    );
    let values: Vec<i64> = column(&sweep, "replay.batch")
        .iter()
        .map(|v| v.as_integer().unwrap())
        .collect();
    assert_eq!(values, [8, 16, 32, 64, 128, 256]);
}

fn random_axis(spec: &str) -> Vec<Value> {
    let sweep = load(&format!(
        r#"
        name = "random"
        base = "../stage1.toml"
        [[axis]]
        key = "policy.epsilon_start"
        random = {spec}
        "#
    ));
    column(&sweep, "policy.epsilon_start")
}

#[test]
fn random_draws_are_reproducible_bounded_and_seeded() {
    let spec = "{ low = 0.3, high = 0.6, draws = 50, seed = 7 }";
    let first = floats(&random_axis(spec));
    assert_eq!(first, floats(&random_axis(spec)));
    assert_eq!(first.len(), 50);
    assert!(first.iter().all(|x| (0.3..=0.6).contains(x)), "{first:?}");
    // Rounded for reading, yet still spread out.
    assert!(
        first
            .iter()
            .all(|x| *x == format!("{x:.6e}").parse::<f64>().unwrap())
    );
    let mut distinct = first.clone();
    distinct.dedup();
    assert!(distinct.len() > 40);

    let other = floats(&random_axis(
        "{ low = 0.3, high = 0.6, draws = 50, seed = 8 }",
    ));
    assert_ne!(first, other);
}

#[test]
fn log_uniform_draws_stay_in_bounds() {
    let values = floats(&random_axis(
        r#"{ low = 1e-5, high = 1e-2, draws = 200, seed = 1, scale = "log" }"#,
    ));
    assert!(
        values.iter().all(|x| (1e-5..=1e-2).contains(x)),
        "{values:?}"
    );
    // Log-uniform: about a third of the draws in each decade.
    let below = values.iter().filter(|x| **x < 1e-4).count();
    assert!((40..=95).contains(&below), "{below} of 200 below 1e-4");
}

#[test]
fn integer_draws_are_integers_covering_both_ends() {
    let values: Vec<i64> =
        random_axis("{ low = 1, high = 3, draws = 100, seed = 3, integer = true }")
            .iter()
            .map(|v| v.as_integer().unwrap())
            .collect();
    assert!(values.iter().all(|x| (1..=3).contains(x)));
    assert!(values.contains(&1) && values.contains(&3));
}

#[test]
fn dotted_keys_create_missing_tables() {
    let sweep = load(
        r#"
        name = "tables"
        base = "../stage1.toml"
        [[axis]]
        key = "replay.batch"
        values = [3]
        [[axis]]
        key = "sim.camera.noise"
        values = [0.01]
        [[axis]]
        key = "policy.epsilon_end"
        values = [0.05]
        "#,
    );
    let config = &sweep.expand()[0].config;
    assert_eq!(lookup(config, "replay.batch"), &Value::Integer(3));
    assert_eq!(lookup(config, "sim.camera.noise"), &Value::Float(0.01));
    // Siblings in an existing table survive.
    assert_eq!(lookup(config, "policy.epsilon_end"), &Value::Float(0.05));
    assert_eq!(lookup(config, "policy.epsilon_start"), &Value::Float(0.5));
}

#[test]
fn descending_into_a_non_table_is_rejected() {
    let message = load_error(
        r#"
        name = "bad"
        base = "../stage1.toml"
        [[axis]]
        key = "seed"
        values = [1]
        [[axis]]
        key = "learning.learning_rate.value"
        values = [1]
        "#,
    );
    assert_contains(
        &message,
        &[
            "[[axis]] number 2",
            "learning.learning_rate.value",
            "`learning.learning_rate` is a float, not a table",
        ],
    );
}

#[test]
fn budget_sets_episodes_and_updates() {
    let sweep = load(
        r#"
        name = "budget"
        base = "../stage1.toml"
        budget = { episodes = 200, updates = 5000 }
        [[axis]]
        key = "seed"
        values = [1, 2]
        "#,
    );
    for run in sweep.expand() {
        assert_eq!(run.config["episodes"], Value::Integer(200));
        assert_eq!(run.config["updates"], Value::Integer(5000));
    }
    // The base as read keeps its own value.
    assert_eq!(sweep.base["episodes"], Value::Integer(400));
}

#[test]
fn budget_and_axis_may_not_set_the_same_key() {
    let message = load_error(
        r#"
        name = "budget"
        base = "../stage1.toml"
        budget = { episodes = 200 }
        [[axis]]
        key = "episodes"
        values = [100, 300]
        "#,
    );
    assert_contains(&message, &["[[axis]] number 1", "`episodes`", "budget"]);
}

#[test]
fn bad_budget_is_rejected() {
    let message = load_error(
        r#"
        name = "budget"
        base = "../stage1.toml"
        budget = { episodes = 0 }
        "#,
    );
    assert_contains(&message, &["episodes must be at least 1"]);
}

#[test]
fn run_ids_are_unique_and_zero_padded() {
    let sweep = load(
        r#"
        name = "ids"
        base = "../stage1.toml"
        [[axis]]
        key = "seed"
        values = [1, 2, 3, 4]
        [[axis]]
        key = "objects"
        values = [5, 10, 15]
        "#,
    );
    let ids: Vec<String> = sweep.expand().into_iter().map(|run| run.id).collect();
    assert_eq!(ids.len(), 12);
    assert_eq!(ids[0], "ids-00");
    assert_eq!(ids[7], "ids-07");
    assert_eq!(ids[11], "ids-11");
    let mut sorted = ids.clone();
    sorted.sort();
    sorted.dedup();
    assert_eq!(sorted, ids, "ids sort in run order without repeats");
}

#[test]
fn no_axes_is_one_run_of_the_base() {
    let sweep = load(
        r#"
        name = "single"
        base = "../stage1.toml"
        budget = { episodes = 10 }
        "#,
    );
    let runs = sweep.expand();
    assert_eq!(runs.len(), 1);
    assert_eq!(runs[0].id, "single-0");
    assert_eq!(runs[0].label(), "");
    assert_eq!(dry_run_listing(&runs), "single-0\n");
}

#[test]
fn config_toml_parses_back_to_the_config() {
    let sweep = load(COMPLETE_WITHOUT_SLURM);
    for run in sweep.expand() {
        let text = run.config_toml();
        let parsed: toml::Table = toml::from_str(&text).unwrap();
        assert_eq!(parsed, run.config, "{text}");
    }
}

const COMPLETE_WITHOUT_SLURM: &str = r#"
name = "stage1-lr"
base = "../stage1.toml"
budget = { episodes = 200 }
[[axis]]
key = "seed"
values = [1, 2]
[[axis]]
key = "learning.learning_rate"
range = { from = 1e-4, to = 1e-3, steps = 3, scale = "log" }
"#;

#[test]
fn dry_run_lists_ids_and_overrides() {
    let sweep = load(COMPLETE_WITHOUT_SLURM);
    let listing = dry_run_listing(&sweep.expand());
    let lines: Vec<&str> = listing.lines().collect();
    assert_eq!(lines.len(), 6);
    assert_eq!(
        lines[0],
        "stage1-lr-0  seed=1 learning.learning_rate=0.0001"
    );
    assert_eq!(
        lines[4],
        "stage1-lr-4  seed=2 learning.learning_rate=0.000316228"
    );
}

#[test]
fn axis_errors_name_the_file_axis_and_problem() {
    let cases = [
        ("key = \"seed\"", "exactly one of"),
        (
            "key = \"seed\"\nvalues = [1]\nrange = { from = 1, to = 2, steps = 2 }",
            "exactly one of",
        ),
        ("key = \"seed\"\nvalues = []", "`values` is empty"),
        (
            "key = \"learning.gamma\"\nrange = { from = 0.1, to = 0.9, steps = 0 }",
            "steps = 0",
        ),
        (
            "key = \"learning.gamma\"\nrange = { from = 0.0, to = 0.9, steps = 3, scale = \"log\" }",
            "positive bounds",
        ),
        (
            "key = \"learning.gamma\"\nrandom = { low = -1.0, high = 1.0, draws = 3, seed = 1, scale = \"log\" }",
            "positive bounds",
        ),
        (
            "key = \"learning.gamma\"\nrandom = { low = 0.9, high = 0.1, draws = 3, seed = 1 }",
            "above high",
        ),
        (
            "key = \"learning.gamma\"\nrandom = { low = 0.1, high = 0.9, draws = 0, seed = 1 }",
            "draws = 0",
        ),
        (
            "key = \"objects\"\nrandom = { low = 1.5, high = 9, draws = 3, seed = 1, integer = true }",
            "must be an integer",
        ),
        ("values = [1]", "`key` is missing"),
        ("key = \"a..b\"\nvalues = [1]", "not a dotted path"),
    ];
    for (axis, problem) in cases {
        let message = load_error(&format!(
            "name = \"bad\"\nbase = \"../stage1.toml\"\n[[axis]]\nkey = \"seed\"\nvalues = [1, 2]\n\
             [[axis]]\n{axis}\n"
        ));
        assert_contains(&message, &["[[axis]] number 2", problem]);
        if let Some(key) = axis.strip_prefix("key = \"") {
            let key = &key[..key.find('"').unwrap()];
            assert_contains(&message, &[key]);
        }
    }
}

#[test]
fn a_key_swept_twice_is_rejected() {
    let message = load_error(
        r#"
        name = "twice"
        base = "../stage1.toml"
        [[axis]]
        key = "seed"
        values = [1, 2]
        [[axis]]
        zip = [ { key = "objects", values = [5] }, { key = "seed", values = [3] } ]
        "#,
    );
    assert_contains(
        &message,
        &[
            "[[axis]] number 2",
            "`seed`",
            "also swept by [[axis]] number 1",
        ],
    );
}

#[test]
fn a_key_nested_in_another_is_rejected() {
    let message = load_error(
        r#"
        name = "nested"
        base = "../stage1.toml"
        [[axis]]
        key = "policy"
        values = [{ epsilon_start = 0.4 }]
        [[axis]]
        key = "policy.epsilon_end"
        values = [0.1]
        "#,
    );
    assert_contains(
        &message,
        &[
            "[[axis]] number 2",
            "overlaps key `policy` of [[axis]] number 1",
        ],
    );
}

#[test]
fn bad_names_are_rejected() {
    for name in ["Stage1", "stage 1", "", "a/b"] {
        let message = load_error(&format!("name = {name:?}\nbase = \"../stage1.toml\"\n"));
        assert_contains(&message, &["name", "a-z, 0-9"]);
    }
}

#[test]
fn unknown_fields_and_wrong_types_keep_tomls_position() {
    let message = load_error("name = \"x\"\nbase = \"../stage1.toml\"\nbudgett = 3\n");
    assert_contains(&message, &["line 3", "budgett"]);
    let message = load_error(
        "name = \"x\"\nbase = \"../stage1.toml\"\n[[axis]]\nkey = \"seed\"\nrange = { from = 1, to = 2, steps = -1 }\n",
    );
    assert_contains(&message, &["line 5"]);
}

#[test]
fn unreadable_base_is_named() {
    let message = load_error("name = \"x\"\nbase = \"../missing.toml\"\n");
    assert_contains(&message, &["cannot read base config", "missing.toml"]);
}

#[test]
fn unparsable_base_is_named_with_its_line_and_column() {
    let (_dir, path) = write_files(
        "name = \"x\"\nbase = \"../stage1.toml\"\n",
        "stage = 1\nseed = = 2\n",
    );
    let message = Sweep::load(&path).unwrap_err().to_string();
    assert_contains(
        &message,
        &[
            &path.display().to_string(),
            "cannot parse base config",
            "stage1.toml",
            "line 2, column",
        ],
    );
}

#[test]
fn unreadable_sweep_file_is_named() {
    let missing = Path::new("no/such/sweep.toml");
    let message = Sweep::load(missing).unwrap_err().to_string();
    assert_contains(&message, &["cannot read sweep file", "no/such/sweep.toml"]);
}
