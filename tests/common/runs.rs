//! A command that must succeed, and the summary of a run in a directory of runs, for the
//! tests of `pushgrasp train` and `pushgrasp sweep`.

use std::borrow::BorrowMut;
use std::path::Path;
use std::process::Command;

use serde_json::Value;

use crate::json::json;

/// Runs the command (a `Command` or the `&mut Command` its builder methods return), which
/// must succeed; returns its standard output.
pub fn succeeds(mut command: impl BorrowMut<Command>) -> String {
    let command = command.borrow_mut();
    let output = command.output().expect("pushgrasp runs");
    assert!(
        output.status.success(),
        "{command:?} failed ({}):\n{}\n{}",
        output.status,
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout).into_owned()
}

/// The summary of run `run` under `dir`.
pub fn summary(dir: &Path, run: &str) -> Value {
    json(&dir.join(run).join("summary.json"))
}
