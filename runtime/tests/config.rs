//! Run configs: the shipped ones load and train their stage; bad fields are refused naming
//! the file and the field; per-actor exploration and row scenes; the replay's capacity in
//! transitions or bytes, and one too large for the machine.

use std::path::Path;

use learner::TrainedNet;
use rundir::config::*;
use sim::Rows;

#[test]
fn apex_rates_run_from_epsilon_to_epsilon_to_the_1_plus_alpha() {
    let apex = ApexEpsilon {
        epsilon: 0.4,
        alpha: 7.0,
    };
    assert!((apex.for_actor(0, 8) - 0.4).abs() < 1e-6);
    assert!((apex.for_actor(7, 8) - 0.4f32.powi(8)).abs() < 1e-7);
    assert!((apex.for_actor(0, 1) - 0.4).abs() < 1e-6);
    let middle = apex.for_actor(3, 8);
    assert!(middle < 0.4 && middle > 0.4f32.powi(8));
}

#[test]
fn row_scenes_are_drawn_at_their_share_and_checked() {
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(5);
    let rows = RowScenes {
        share: 0.25,
        objects: 4,
        lines: 2,
    };
    let pack = Rows {
        blocks: 4,
        lines: 2,
    };
    let drawn: Vec<Rows> = (0..4000).map(|_| rows.draw(&mut rng)).collect();
    assert!(drawn.iter().all(|&n| n == Rows::NONE || n == pack));
    let share = drawn.iter().filter(|&&n| n == pack).count() as f64 / 4000.0;
    assert!((share - 0.25).abs() < 0.03, "{share}");

    let stage1 = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/stage1.toml");
    let text = std::fs::read_to_string(stage1).unwrap();
    let with = |rows: &str| RunConfig::parse(&format!("{text}\n[rows]\n{rows}"), "run.toml");
    with("share = 0.3\nobjects = 4").unwrap();
    let err = with("share = 1.5").unwrap_err().to_string();
    assert!(
        err.contains("run.toml") && err.contains("rows.share"),
        "{err}"
    );
    let err = with("share = 0.3\nobjects = 9").unwrap_err().to_string();
    assert!(err.contains("rows.objects"), "{err}");
    let err = with("share = 0.3\nobjects = 3\nlines = 4")
        .unwrap_err()
        .to_string();
    assert!(err.contains("rows.lines"), "{err}");
}

#[test]
fn grasp_trials_are_refused_where_the_grasp_net_is_frozen() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
    let with_trials = |stage: u8| {
        let text = std::fs::read_to_string(dir.join(format!("stage{stage}.toml"))).unwrap();
        let mut table: toml::Table = toml::from_str(&text).unwrap();
        table.insert("grasp_trials".into(), 2.into());
        RunConfig::parse(&toml::to_string(&table).unwrap(), "run.toml")
    };
    assert_eq!(with_trials(1).unwrap().grasp_trials, 2);
    assert_eq!(with_trials(3).unwrap().grasp_trials, 2);
    let err = with_trials(2).unwrap_err().to_string();
    assert!(
        err.contains("run.toml") && err.contains("grasp_trials"),
        "{err}"
    );
}

/// Stage 1's config with `field` (`table.key`, or a top-level key) set to `value` (TOML),
/// parsed.
fn stage1_with(field: &str, value: &str) -> anyhow::Result<RunConfig> {
    let stage1 = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/stage1.toml");
    let text = std::fs::read_to_string(stage1).unwrap();
    let mut config: toml::Table = toml::from_str(&text).unwrap();
    let value: toml::Table = toml::from_str(&format!("v = {value}")).unwrap();
    let (table, key) = match field.split_once('.') {
        Some((table, key)) => (
            config
                .entry(table)
                .or_insert_with(|| toml::Table::new().into())
                .as_table_mut()
                .unwrap(),
            key,
        ),
        None => (&mut config, field),
    };
    table.insert(key.into(), value["v"].clone());
    RunConfig::parse(&toml::to_string(&config).unwrap(), "run.toml")
}

#[test]
fn the_replay_capacity_is_transitions_or_bytes_and_must_fit_the_machine() {
    use buffer::Capacity;
    let config = stage1_with("buffer.capacity", "5000").unwrap();
    assert_eq!(config.buffer.capacity, Capacity::Steps(5000));
    let mut config = stage1_with("buffer.capacity", "\"64 MiB\"").unwrap();
    assert_eq!(config.buffer.capacity, Capacity::Bytes(64 << 20));
    config.size_buffer().unwrap();
    let step = buffer::bytes_per_step(&config.sim, config.objects).unwrap();
    assert!(
        (1_000..20_000).contains(&step),
        "{step} bytes a stored step at 112"
    );
    assert_eq!(
        config.buffer.capacity,
        Capacity::Steps((64 << 20) / (2 * step))
    );
    // The resolved config is what the run directory keeps, and reads back the same.
    let written = toml::to_string(&config).unwrap();
    assert!(written.contains(&format!("capacity = {}", (64 << 20) / (2 * step))));
    assert_eq!(RunConfig::parse(&written, "copy").unwrap(), config);

    // TOML names the line and shows the key; the message says what is accepted.
    let err = stage1_with("buffer.capacity", "\"8 parsecs\"")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("run.toml: TOML parse error at line"),
        "{err}"
    );
    assert!(err.contains("capacity = \"8 parsecs\""), "{err}");
    assert!(err.contains("nor a size such as \"8 GiB\""), "{err}");
    // 2 x 4e9 transitions of a few KB: terabytes, more than any machine this runs on.
    let mut huge = stage1_with("buffer.capacity", "4000000000").unwrap();
    let err = huge.size_buffer().unwrap_err().to_string();
    assert!(err.contains("buffer.capacity = 4000000000"), "{err}");
    assert!(err.contains("GB") && err.contains("available"), "{err}");
}

#[test]
fn a_field_out_of_its_part_s_range_is_refused_naming_the_file_and_the_field() {
    // `field` is `table.key`; the error must name it (a nested table's key after it).
    let with = stage1_with;
    for (field, value) in [
        ("sim.physics_hz", "0.0"),
        ("sim.grasp_lift", "0.03"),
        ("sim.drop_square", "1.0"),
        ("policy.q_star", "nan"),
        ("policy.grasp_margin", "-0.004"),
        ("policy.crowded_border", "1.2"),
        ("policy.goal_guard", "-0.02"),
        ("policy.landing_guard", "-0.004"),
        ("policy.landing_subpixels", "4"),
        ("policy.landing_subpixels", "11"),
        ("policy.landing_retreat", "0.008"),
        ("policy.grasp_landing_guard", "-0.004"),
        ("policy.squeeze_guard", "-0.3"),
        ("policy.push_reach", "-0.04"),
        ("policy.epsilon_start", "3.0"),
        ("policy.epsilon_decay", "1.5"),
        ("net.trunk_widths", "[]"),
        ("net.context_dilations", "[1, 0]"),
        ("net.head_width", "0"),
        ("learning.learning_rate", "-1.0"),
        ("learning.lr_decay", "{ to = 0.0, over_updates = 10 }"),
        ("learning.beta_1", "1.5"),
        ("learning.gamma", "1.0"),
        ("learning.huber_delta", "0.0"),
        ("learning.polyak_rate", "0.0"),
        ("buffer.capacity", "0"),
        ("run.heartbeat_timeout_s", "0.0"),
        ("buffer.samples_per_insert", "0.0"),
        ("buffer.positive_share", "1.5"),
        ("crowded_goals", "-0.5"),
    ] {
        let err = with(field, value).unwrap_err().to_string();
        assert!(err.starts_with(&format!("run.toml: {field}")), "{err}");
    }
    // The edge of each range is accepted.
    for (field, value) in [
        ("sim.grasp_lift", "0.05"),
        ("policy.epsilon_decay", "1.0"),
        ("policy.landing_subpixels", "9"),
        ("learning.gamma", "0.0"),
        ("learning.polyak_rate", "1.0"),
    ] {
        with(field, value).unwrap();
    }
}

#[test]
fn the_shipped_stage_configs_are_valid_and_train_their_stage() {
    for (stage, mode, nets) in [
        (1, policy::Mode::GraspOnly, &[TrainedNet::Grasp][..]),
        (2, policy::Mode::PushGrasp, &[TrainedNet::Push][..]),
        (
            3,
            policy::Mode::PushGrasp,
            &[TrainedNet::Grasp, TrainedNet::Push][..],
        ),
    ] {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../configs/stage{stage}.toml"));
        let config = RunConfig::load(&path).unwrap();
        assert_eq!(config.stage, stage);
        assert_eq!(config.mode(), mode);
        assert_eq!(config.trained_nets(), nets);
        assert_eq!(config.init_from, None);
    }
}
