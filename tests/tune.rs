//! CubeCL's autotune on this machine's wgpu adapter (lavapipe in CI), tuning for real, in
//! processes of their own so that every key tunes into a fresh cache:
//! - a tune whose candidates tune in turn completes: a 1x1 convolution's tune measures
//!   `conv_im2col_1x1`, which multiplies through the autotuned matmul, so the matmul's key is
//!   reached inside the convolution's measurement (vendor/README.md);
//! - the results are kept on disk (`PUSHGRASP_TUNE_CACHE`), and the next process loads every
//!   key it needs from there instead of tuning it again.
#![cfg(feature = "wgpu")]

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use burn::prelude::*;
use burn::tensor::module;
use burn::tensor::ops::ConvOptions;

/// Far longer than a tune of the convolution on lavapipe takes (6.6 s here the first time,
/// 0.1 s in later runs).
const HUNG_AFTER: Duration = Duration::from_secs(600);

/// Runs [`convolves_1x1`] in a process of its own with `cache` as its tune cache and CubeCL's
/// autotune log in `log`; fails if it fails or has not finished after [`HUNG_AFTER`].
fn convolve_in_a_process(cache: &Path, log: &Path) {
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args(["--ignored", "--exact", "convolves_1x1", "--nocapture"])
        .env("PUSHGRASP_TUNE_CACHE", cache)
        .env("PUSHGRASP_TUNE_SOFTWARE", "1")
        .env("CUBECL_DEBUG_LOG", log)
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if started.elapsed() > HUNG_AFTER {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("the convolution's tune had not completed after {HUNG_AFTER:?}");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(status.success(), "the convolving process failed: {status}");
}

/// The tune cache's look-ups in an autotune log: `Hit` or `Miss` each.
fn look_ups(log: &Path) -> Vec<String> {
    std::fs::read_to_string(log)
        .unwrap_or_default()
        .lines()
        .filter(|line| line.contains("look up key="))
        .map(str::to_string)
        .collect()
}

#[test]
fn a_tune_inside_a_tune_completes_and_the_next_process_loads_it() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("tune");
    let (first, second) = (dir.path().join("first.log"), dir.path().join("second.log"));

    convolve_in_a_process(&cache, &first);
    let tuned = look_ups(&first);
    assert!(
        tuned.iter().any(|line| line.contains("Miss")),
        "the first process tuned nothing: {tuned:?}"
    );
    let stored = std::fs::read_dir(&cache)
        .unwrap()
        .filter_map(Result::ok)
        .any(|entry| entry.path().extension().is_some_and(|e| e == "db"));
    assert!(stored, "no tune database in {}", cache.display());

    convolve_in_a_process(&cache, &second);
    let loaded = look_ups(&second);
    assert!(!loaded.is_empty(), "the second process looked nothing up");
    assert!(
        loaded.iter().all(|line| line.contains("Hit")),
        "the second process tuned again: {loaded:?}"
    );
}

/// The convolution the processes above run (`--ignored`: not a test of its own).
#[test]
#[ignore]
fn convolves_1x1() {
    let device = qnet::Backend::Wgpu.open().expect("a wgpu adapter").device;
    let input = Tensor::<4>::ones([1, 8, 16, 16], &device);
    let weight = Tensor::<4>::ones([8, 8, 1, 1], &device);
    let options = ConvOptions::new([1, 1], [0, 0], [1, 1], 1);
    let output = module::conv2d(input, weight, None, options);
    let values = output.into_data().try_to_vec::<f32>().expect("f32 values");
    assert_eq!(values.len(), 8 * 16 * 16);
    assert!(values.iter().all(|v| (v - 8.0).abs() < 1e-4), "{values:?}");
}
