//! The `pushgrasp` program end to end: each test runs the built binary as a person would and
//! checks what it wrote.

use std::path::{Path, PathBuf};

use sim::{Arrangement, OriginalOptions};

mod common;
use common::{pushgrasp_fails, pushgrasp_ok};

/// The paper's challenging case 00, when the original files are here.
fn original_case_00() -> Option<PathBuf> {
    let cases = std::env::var_os("PUSHGRASP_TEST_CASES")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../shared/reference/test-cases"
            ))
        });
    if !cases.is_dir() {
        eprintln!("skipping: {} not found", cases.display());
        return None;
    }
    Some(cases.join("Efficient_goal-oriented_push-grasping_synergy/test-10-obj-00.txt"))
}

fn path_arg(path: &Path) -> &str {
    path.to_str().expect("a utf-8 path")
}

/// The sides of `<stem>-colour.png`, `-height.png` and `-ids.png` in `dir`.
fn heightmap_sizes(dir: &Path, stem: &str) -> Vec<(u32, u32)> {
    ["colour", "height", "ids"]
        .iter()
        .map(|kind| {
            let path = dir.join(format!("{stem}-{kind}.png"));
            let picture = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            (picture.width(), picture.height())
        })
        .collect()
}

#[test]
fn scene_render_writes_heightmaps_at_the_pixel_size() {
    // (extra arguments, pixels per side)
    for (extra, side) in [(&[][..], 224), (&["--pixel-size", "0.004"][..], 112)] {
        let out = tempfile::tempdir().unwrap();
        let mut args = vec!["scene", "render", "--objects", "5", "--seed", "3"];
        args.extend(extra);
        args.extend(["--out", path_arg(out.path())]);
        pushgrasp_ok(&args);
        assert_eq!(
            heightmap_sizes(out.path(), "random-5-seed3"),
            vec![(side, side); 3],
            "{args:?}"
        );
    }
}

#[test]
fn scene_render_loads_an_arrangement() {
    let out = tempfile::tempdir().unwrap();
    pushgrasp_ok(&[
        "scene",
        "render",
        "--arrangement",
        "configs/arrangements/challenging-04.toml",
        "--out",
        path_arg(out.path()),
    ]);
    assert_eq!(
        heightmap_sizes(out.path(), "challenging-04"),
        vec![(224, 224); 3]
    );
}

#[test]
fn scene_render_reports_a_malformed_arrangement_with_its_line() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.txt");
    std::fs::write(
        &file,
        "4.obj 0.5 0.5 0.5 -0.5 0.0 0.025 0 0 0\n4.obj 0.5 0.5 0.5 -0.5 0.0\n",
    )
    .unwrap();
    let stderr = pushgrasp_fails(&[
        "scene",
        "render",
        "--arrangement",
        path_arg(&file),
        "--out",
        path_arg(dir.path()),
    ]);
    let place = format!("{}:2:", file.display());
    assert!(
        stderr.contains(&place),
        "stderr should name {place}:\n{stderr}"
    );
}

#[test]
fn scene_grasps_tells_grasps_that_fit_the_jaws_from_those_that_do_not() {
    // A lone bar as long as the jaws open wide: they close across it, not along it.
    let bar = "configs/probes/lone-bar.toml";
    let stdout = pushgrasp_ok(&[
        "scene",
        "grasps",
        "--arrangements",
        bar,
        "--stride",
        "3",
        "--jitters",
        "1",
        "--json",
    ]);
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let case = &report["cases"][0];
    assert_eq!(case["case"], "lone-bar", "{stdout}");
    let candidates = case["candidates"].as_u64().unwrap();
    assert!(candidates > 0 && candidates.is_multiple_of(8), "{stdout}");
    let (always, never) = (
        case["always"].as_f64().unwrap(),
        case["never"].as_f64().unwrap(),
    );
    assert!(
        always > 0.2 && never > 0.2,
        "some grasps fit, some do not: {stdout}"
    );
    // The success of the grasps each grasp margin keeps: a share, for every margin shown.
    let inside = case["inside"].as_array().unwrap();
    let margins: Vec<f64> = inside
        .iter()
        .map(|m| m["margin"].as_f64().unwrap())
        .collect();
    assert_eq!(margins.len(), 3, "{stdout}");
    assert!((margins[0] - 0.004).abs() < 1e-6, "{stdout}");
    assert!(
        inside.iter().all(|m| m["success"]
            .as_f64()
            .is_some_and(|s| (0.0..=1.0).contains(&s))),
        "a bar 5 cm wide keeps grasps at every margin: {stdout}"
    );
    // The scripted grasp closes across a lone bar at its centre: it picks it.
    assert_eq!(case["scripted"].as_f64(), Some(1.0), "{stdout}");

    let dir = tempfile::tempdir().unwrap();
    let no_goal = dir.path().join("no-goal.toml");
    let text = std::fs::read_to_string(bar).unwrap();
    std::fs::write(&no_goal, text.replace("goal = 1", "")).unwrap();
    let stderr = pushgrasp_fails(&["scene", "grasps", "--arrangements", path_arg(&no_goal)]);
    assert!(
        stderr.contains("no-goal.toml") && stderr.contains("names no goal"),
        "{stderr}"
    );
}

#[test]
fn scene_grasps_draws_random_scenes_with_their_goal_in_the_row() {
    let args = |row: &'static str| {
        let stdout = pushgrasp_ok(&[
            "scene",
            "grasps",
            "--random",
            "2",
            "--objects",
            "4",
            "--row",
            row,
            "--stride",
            "4",
            "--jitters",
            "1",
            "--json",
        ]);
        let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        report["cases"].as_array().unwrap().clone()
    };
    let plain = args("0");
    let names: Vec<&str> = plain.iter().map(|c| c["case"].as_str().unwrap()).collect();
    assert_eq!(names, ["random-4-0", "random-4-1"]);
    for case in &plain {
        assert!(case["candidates"].as_u64().unwrap() > 0, "{case}");
        let success = case["success"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&success), "{case}");
    }
    let rows = args("3");
    assert_eq!(rows[0]["case"], "random-4-row3-0");
    // The row's blocks are objects 1 to 3.
    assert!(
        rows.iter().all(|c| c["goal"].as_u64().unwrap() <= 3),
        "{rows:?}"
    );

    let stderr = pushgrasp_fails(&["scene", "grasps", "--json"]);
    assert!(
        stderr.contains("--arrangements") && stderr.contains("--random"),
        "{stderr}"
    );
    // No scenes at all is refused, not an empty table.
    let stderr = pushgrasp_fails(&["scene", "grasps", "--random", "0"]);
    assert!(stderr.contains("--random"), "{stderr}");
}

#[test]
fn scene_convert_names_the_goal() {
    let Some(original) = original_case_00() else {
        return;
    };
    let stdout = pushgrasp_ok(&["scene", "convert", path_arg(&original), "--goal-slot", "4"]);
    let converted = Arrangement::parse_toml(&stdout, Path::new("converted.toml"))
        .unwrap_or_else(|e| panic!("{e}\n{stdout}"));
    assert_eq!(converted.goal, Some(5));
    let loaded = Arrangement::read(&original, &OriginalOptions::default()).unwrap();
    assert_eq!(converted.objects, loaded.objects);
}

#[test]
fn scene_convert_refuses_a_goal_off_the_table() {
    let Some(original) = original_case_00() else {
        return;
    };
    let loaded = Arrangement::read(&original, &OriginalOptions::default()).unwrap();
    assert!(
        loaded.objects.iter().all(|o| o.id != 1),
        "slot 0 of {} should be parked off the workspace",
        original.display()
    );
    let stderr = pushgrasp_fails(&["scene", "convert", path_arg(&original), "--goal-slot", "0"]);
    assert!(
        stderr.contains("goal slot 0 is not an object on the table"),
        "{stderr}"
    );
}

#[test]
fn scene_convert_keeps_a_named_goal_and_refuses_a_goal_slot_besides_it() {
    let dir = tempfile::tempdir().unwrap();
    let original = dir.path().join("named.txt");
    std::fs::write(
        &original,
        "block 4.obj -0.6 0.0 0.026 0 0 0\nred 8.obj -0.5 0.0 0.026 0 0 0\n",
    )
    .unwrap();
    let stdout = pushgrasp_ok(&["scene", "convert", path_arg(&original)]);
    let converted = Arrangement::parse_toml(&stdout, Path::new("converted.toml"))
        .unwrap_or_else(|e| panic!("{e}\n{stdout}"));
    assert_eq!(converted.goal, Some(2), "{stdout}");
    let stderr = pushgrasp_fails(&["scene", "convert", path_arg(&original), "--goal-slot", "0"]);
    assert!(
        stderr.contains("named.txt") && stderr.contains("names its goal"),
        "{stderr}"
    );
}

#[test]
fn episode_writes_its_summary_and_observations() {
    let out = tempfile::tempdir().unwrap();
    pushgrasp_ok(&[
        "episode",
        "--objects",
        "6",
        "--seed",
        "2",
        "--max-actions",
        "3",
        "--out",
        path_arg(out.path()),
    ]);
    let summary = std::fs::read_to_string(out.path().join("episode.json")).unwrap();
    let summary: serde_json::Value = serde_json::from_str(&summary).unwrap();
    let goal = summary["goal"].as_u64().expect("a numeric goal");
    assert!((1..=6).contains(&goal), "goal {goal}");
    let steps = summary["steps"].as_array().expect("a steps array");
    assert!((1..=3).contains(&steps.len()), "{} steps", steps.len());
    assert_eq!(heightmap_sizes(out.path(), "step00"), vec![(224, 224); 3]);
}

#[test]
fn bench_transport_reports_every_figure_of_a_short_run() {
    let stdout = pushgrasp_ok(&[
        "bench",
        "transport",
        "--json",
        "--messages",
        "16",
        "--size",
        "65536",
        "--reps",
        "1",
        "--latency-messages",
        "4",
    ]);
    let figures = last_line_figures(&stdout);
    let rate = |key: &str| figures[key].as_f64();
    for publishers in [1, 2, 4] {
        for via in ["iceoryx2", "unix_socket"] {
            let key = format!("{via}_gbps_{publishers}");
            assert!(rate(&key).is_some_and(|v| v > 0.0), "{key}: {figures}");
        }
    }
    for key in [
        "memcpy_gbps",
        "iceoryx2_p50_latency_us",
        "iceoryx2_gbps_1_same_cpu",
        "handoff_gbps_same_cpu",
    ] {
        assert!(rate(key).is_some_and(|v| v > 0.0), "{key}: {figures}");
    }
    // Measured where this machine has a second CPU, null where it has not.
    for key in ["iceoryx2_gbps_1_two_cpus", "handoff_gbps_two_cpus"] {
        assert!(
            figures[key].is_null() || rate(key).is_some_and(|v| v > 0.0),
            "{key}: {figures}"
        );
    }
}

#[test]
fn bench_soak_samples_every_process_of_a_short_run_past_its_full_replay() {
    let stdout = pushgrasp_ok(&[
        "bench",
        "soak",
        "--json",
        "--actors",
        "1",
        "--capacity",
        "10",
        "--minutes",
        "0.2",
        "--every-s",
        "1",
    ]);
    let figures = last_line_figures(&stdout);
    assert_eq!(figures["replay_full"], true, "{figures}");
    for process in ["launcher", "buffer", "learner", "actor-0-0"] {
        let start = figures[format!("rss_mb_{process}_start")].as_f64();
        assert!(start.is_some_and(|mb| mb > 1.0), "{process}: {figures}");
        assert!(
            figures[format!("rss_growth_pct_{process}")].is_number(),
            "{process}: {figures}"
        );
    }
    assert!(figures["rss_growth_pct_max"].is_number(), "{figures}");
}

/// The JSON object of figures a `bench ... --json` prints as its last line.
fn last_line_figures(stdout: &str) -> serde_json::Value {
    let last = stdout.lines().last().expect("a line of figures");
    serde_json::from_str(last).unwrap()
}
