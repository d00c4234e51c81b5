//! Peers that run in Python beside ours (cpprb, onnxruntime, numpy): which interpreter, and a
//! script's figures.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result, bail};
use serde_json::{Map, Value};

/// Where `make bench` installs the peers, relative to the repository root.
const BENCH_VENV_PYTHON: &str = "target/bench-venv/bin/python3";

/// The venv `make bench` made, else the system's `python3`.
pub fn default_python() -> PathBuf {
    let venv = Path::new(BENCH_VENV_PYTHON);
    if venv.exists() {
        venv.to_path_buf()
    } else {
        PathBuf::from("python3")
    }
}

/// Runs `script` with `args` after `imports` (Python import statements, one a line, beside
/// `json`, `os`, `sys` and `time`); its last line of output is one JSON object of figures.
/// An import that fails is an error saying what was missing.
pub fn script_figures(
    python: &Path,
    imports: &str,
    script: &str,
    args: &[String],
) -> Result<Map<String, Value>> {
    let imports: String = imports
        .lines()
        .map(|line| format!("    {line}\n"))
        .collect();
    let program = format!(
        "import json, os, sys, time\ntry:\n{imports}except ImportError as e:\n    \
         print(json.dumps({{\"missing\": f\"{{e}} (Python {{sys.version.split()[0]}})\"}}))\n    \
         sys.exit(0)\n{script}"
    );
    let output = Command::new(python)
        .arg("-c")
        .arg(program)
        .args(args)
        .output()
        .with_context(|| format!("{} did not start", python.display()))?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        bail!(
            "{} failed: {}",
            python.display(),
            stderr
                .lines()
                .rev()
                .find(|line| !line.trim().is_empty())
                .unwrap_or("no message")
        );
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    let last = stdout
        .lines()
        .last()
        .context("the script printed nothing")?;
    let figures: Map<String, Value> =
        serde_json::from_str(last).context("the script printed no JSON object")?;
    if let Some(missing) = figures.get("missing") {
        bail!("{}", missing.as_str().unwrap_or("a module is missing"));
    }
    Ok(figures)
}
