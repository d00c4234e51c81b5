//! Running the `pushgrasp` binary from the checkout's root, for the integration tests.

use std::process::{Command, Output};

/// Runs `pushgrasp <args>` from the checkout's root.
pub fn pushgrasp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pushgrasp"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("pushgrasp runs")
}

/// Runs `pushgrasp <args>`, which must succeed, and returns its stdout.
pub fn pushgrasp_ok(args: &[&str]) -> String {
    let output = pushgrasp(args);
    assert!(
        output.status.success(),
        "pushgrasp {args:?} failed ({}):\n{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).expect("utf-8 output")
}

/// Runs `pushgrasp <args>`, which must fail, and returns its stderr.
pub fn pushgrasp_fails(args: &[&str]) -> String {
    let output = pushgrasp(args);
    assert!(
        !output.status.success(),
        "pushgrasp {args:?} should have failed; it printed:\n{}",
        String::from_utf8_lossy(&output.stdout)
    );
    String::from_utf8(output.stderr).expect("utf-8 output")
}
