//! Following a submitted job array through Slurm's `sacct` and `squeue` output.

use std::collections::BTreeMap;

use crate::error::SweepError;

/// Slurm's largest `MaxArraySize`: no array index reaches it, so a wider range is garbage.
const MAX_ARRAY_SIZE: usize = 4_000_001;

/// The state of one array task.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum JobState {
    /// Waiting to start (or requeued).
    Pending,
    /// Running, or starting up or winding down.
    Running,
    /// Finished with exit code 0.
    Completed,
    /// Finished with a non-zero exit code.
    Failed,
    /// Cancelled by a user or an administrator.
    Cancelled,
    /// Any other Slurm state, e.g. `TIMEOUT` or `OUT_OF_MEMORY`, as Slurm spells it.
    Other(String),
}

impl JobState {
    /// Reads a state as `sacct` (`CANCELLED by 0`) or `squeue -o %T` prints it.
    pub fn parse(text: &str) -> JobState {
        let word = text.split_whitespace().next().unwrap_or("");
        match word {
            "PENDING" | "REQUEUED" => JobState::Pending,
            "RUNNING" | "CONFIGURING" | "COMPLETING" => JobState::Running,
            "COMPLETED" => JobState::Completed,
            "FAILED" => JobState::Failed,
            "CANCELLED" => JobState::Cancelled,
            other => JobState::Other(other.to_string()),
        }
    }

    /// Whether the task has ended and will not run again by itself.
    pub fn is_finished(&self) -> bool {
        match self {
            JobState::Pending | JobState::Running => false,
            JobState::Completed | JobState::Failed | JobState::Cancelled => true,
            JobState::Other(state) => matches!(
                state.as_str(),
                "TIMEOUT" | "OUT_OF_MEMORY" | "NODE_FAIL" | "BOOT_FAIL" | "DEADLINE" | "PREEMPTED"
            ),
        }
    }
}

/// Parses `sacct --parsable2 --noheader --format=JobID,State` output for one job array into
/// the state of each array index. Step lines (`1234_1.batch`, `1234_1.extern`) are skipped;
/// bracketed ranges of pending tasks (`1234_[2-4,7%2]`) give every index they name.
pub fn parse_sacct(text: &str) -> Result<BTreeMap<usize, JobState>, SweepError> {
    parse_task_lines(text)
}

/// Parses `squeue --noheader --format=%i|%T` output for one job array, like [`parse_sacct`].
/// Tasks that have left the queue are absent.
pub fn parse_squeue(text: &str) -> Result<BTreeMap<usize, JobState>, SweepError> {
    parse_task_lines(text)
}

/// `<job>_<index or [ranges]>|<state>` lines; later lines win for an index seen twice.
fn parse_task_lines(text: &str) -> Result<BTreeMap<usize, JobState>, SweepError> {
    let mut states = BTreeMap::new();
    let mut array_job: Option<&str> = None;
    for (number, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let fail = |message: String| SweepError::SlurmOutput {
            line: number + 1,
            text: line.to_string(),
            message,
        };
        let (id, state) = line
            .split_once('|')
            .ok_or_else(|| fail("expected `<job id>|<state>`".to_string()))?;
        let (job, task) = id
            .split_once('_')
            .ok_or_else(|| fail("not a job array task (`<job>_<index>`)".to_string()))?;
        if job.is_empty() || !job.bytes().all(|b| b.is_ascii_digit()) {
            return Err(fail(format!("job id {job:?} is not a number")));
        }
        match array_job {
            Some(seen) if seen != job => {
                return Err(fail(format!(
                    "lines from two job arrays, {seen} and {job}; give one array's lines"
                )));
            }
            _ => array_job = Some(job),
        }
        // Steps of a task (`.batch`, `.extern`, `.0`) report on parts, not the task.
        if task.contains('.') {
            continue;
        }
        let state = JobState::parse(state);
        for index in task_indices(task).map_err(fail)? {
            states.insert(index, state.clone());
        }
    }
    Ok(states)
}

/// `7` or `[2-4,7%2]` as array indices (the `%` limit says nothing about which).
fn task_indices(task: &str) -> Result<Vec<usize>, String> {
    let Some(inner) = task.strip_prefix('[') else {
        return Ok(vec![parse_index(task)?]);
    };
    let inner = inner
        .strip_suffix(']')
        .ok_or_else(|| format!("unclosed range {task:?}"))?;
    let list = inner.split_once('%').map_or(inner, |(list, _limit)| list);
    let mut indices = Vec::new();
    for item in list.split(',') {
        match item.split_once('-') {
            Some((first, last)) => {
                let (first, last) = (parse_index(first)?, parse_index(last)?);
                if first > last || last - first >= MAX_ARRAY_SIZE {
                    return Err(format!("bad index range {item:?}"));
                }
                indices.extend(first..=last);
            }
            None => indices.push(parse_index(item)?),
        }
    }
    Ok(indices)
}

fn parse_index(text: &str) -> Result<usize, String> {
    // `usize::from_str` would also take a leading `+`.
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return Err(format!("array index {text:?} is not a number"));
    }
    text.parse()
        .map_err(|_| format!("array index {text:?} is too large"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indices_expand_lists_ranges_and_limits() {
        assert_eq!(task_indices("3").unwrap(), vec![3]);
        assert_eq!(task_indices("[2-4,7%2]").unwrap(), vec![2, 3, 4, 7]);
        assert_eq!(task_indices("[0,5-6]").unwrap(), vec![0, 5, 6]);
        assert!(task_indices("[4-2]").is_err());
        assert!(task_indices("[2-4").is_err());
        assert!(task_indices("+3").is_err());
        assert!(task_indices("").is_err());
    }

    #[test]
    fn states_read_their_first_word() {
        assert_eq!(JobState::parse("CANCELLED by 0"), JobState::Cancelled);
        assert_eq!(JobState::parse("COMPLETING"), JobState::Running);
        assert_eq!(
            JobState::parse("TIMEOUT"),
            JobState::Other("TIMEOUT".to_string())
        );
        assert!(JobState::parse("TIMEOUT").is_finished());
        assert!(!JobState::parse("PENDING").is_finished());
    }
}
