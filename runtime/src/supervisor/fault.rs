//! A role's fault as the run's summary records it, and the reason a failed role process gave.

use std::path::Path;

use serde::{Deserialize, Serialize};

/// The error a failed role process printed last (its log's last "Error:" paragraph).
pub(super) fn last_error(log: &Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    let start = text.rfind("Error: ")?;
    let error = text[start + "Error: ".len()..].trim();
    // anyhow's backtrace, if any, follows a blank line.
    Some(
        error
            .split("\n\n")
            .next()
            .unwrap_or(error)
            .replace('\n', " "),
    )
}

/// A role that failed during a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Fault {
    /// The role's name (`actor-0-1`, `learner`, ...).
    pub role: String,
    /// Seconds from the launcher's start to when it noticed.
    pub at_s: f64,
    pub cause: String,
    /// Whether it was started again and the run went on (a joined host: it came back).
    pub restarted: bool,
    /// For an actor: the messages of its stream that never reached the buffer (filled in
    /// from the buffer's counts when the run ends).
    #[serde(default)]
    pub lost_messages: Option<u64>,
}
