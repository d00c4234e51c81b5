//! A JSON file a run wrote, read back, and the counts in it, for the integration tests that
//! start runs.

use std::path::Path;

use serde_json::Value;

/// The JSON file at `path`; a file that is missing or not JSON fails the test, naming it.
pub fn json(path: &Path) -> Value {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `value` as a count; anything else fails the test.
pub fn u(value: &Value) -> u64 {
    value
        .as_u64()
        .unwrap_or_else(|| panic!("{value} is not a count"))
}
