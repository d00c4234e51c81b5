//! A role's fault as the run's summary records it, and the reason a failed role process gave.

use std::path::Path;

/// The error a failed role process printed last (its log's last "Error:" paragraph, as
/// `main` prints an error), with its causes after it on one line, as `{:#}` writes them.
pub(super) fn last_error(log: &Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    let start = text.rfind("Error: ")?;
    let mut paragraphs = text[start + "Error: ".len()..].trim().split("\n\n");
    let mut error = paragraphs.next()?.replace('\n', " ");
    // anyhow's causes, numbered (or one alone), then its backtrace, if any.
    if let Some(causes) = paragraphs.next().and_then(|p| p.strip_prefix("Caused by:")) {
        for line in causes.lines().map(str::trim).filter(|l| !l.is_empty()) {
            // "0: cause" when there are several, the cause alone when one.
            let cause = match line.split_once(": ") {
                Some((n, cause)) if n.parse::<u32>().is_ok() => cause,
                _ => line,
            };
            error.push_str(": ");
            error.push_str(cause);
        }
    }
    Some(error)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_last_error_comes_with_its_causes_on_one_line() {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("learner.log");
        let printed = "buffer: restored 20 items\nError: first failure\n\nError: loading the \
            checkpoint\n\nCaused by:\n    0: reading manifest.toml\n    1: No such file or \
            directory (os error 2)\n\nStack backtrace:\n   0: main\n";
        std::fs::write(&log, printed).unwrap();
        assert_eq!(
            last_error(&log).unwrap(),
            "loading the checkpoint: reading manifest.toml: No such file or directory (os error 2)"
        );
        std::fs::write(
            &log,
            "Error: cannot open\n\nCaused by:\n    permission denied\n",
        )
        .unwrap();
        assert_eq!(last_error(&log).unwrap(), "cannot open: permission denied");
        std::fs::write(&log, "Error: alone\nover two lines\n").unwrap();
        assert_eq!(last_error(&log).unwrap(), "alone over two lines");
    }
}
