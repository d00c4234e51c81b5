//! The local backend: the sweep's runs as a bounded pool of `pushgrasp train` child processes
//! of this binary, with one progress view for the whole sweep. A failed run is reported and
//! the others go on; Ctrl-C or SIGTERM is passed on to the runs, which stop in order (their
//! checkpoints and snapshots written), and the sweep exits.

use std::collections::VecDeque;
use std::fs::OpenOptions;
use std::io::{IsTerminal, Write};
use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use signal_hook::consts::{SIGINT, SIGTERM};

use super::dir::{RunState, SweepDir, SweepState};
use super::plan::Plan;

/// How often the pool looks at its children.
const POLL: Duration = Duration::from_millis(100);
/// How often the progress bar re-reads the running runs' episode counts.
const REFRESH: Duration = Duration::from_secs(1);
/// How often a plain progress line is printed without a terminal (as `train` does).
const PLAIN_EVERY: Duration = Duration::from_secs(10);

/// A run in progress.
struct Live {
    index: usize,
    child: Child,
}

/// The runs in progress. Those still running when it is dropped (the sweep itself failed)
/// are stopped as Ctrl-C would stop them, so that no run outlives its sweep unseen.
#[derive(Default)]
struct Pool {
    live: Vec<Live>,
}

impl Drop for Pool {
    fn drop(&mut self) {
        for run in &self.live {
            send_signal(run.child.id(), "TERM");
        }
        for run in &mut self.live {
            let _ = run.child.wait();
        }
    }
}

pub fn run(
    dir: &SweepDir,
    mut state: SweepState,
    plan: &Plan,
    max_parallel: Option<u32>,
) -> Result<()> {
    let max_parallel =
        max_parallel.map_or_else(|| default_parallel(plan.max_actors()), |n| n as usize);
    let mut queue = VecDeque::new();
    for (index, entry) in state.runs.iter().enumerate() {
        if !dir.finished(&entry.id)? {
            queue.push_back(index);
        }
    }
    let to_run = queue.len();
    println!(
        "sweep {}: {} runs, {} to run, at most {max_parallel} at once; run directories in {}, \
         their output in {}",
        state.name,
        state.runs.len(),
        to_run,
        dir.path().display(),
        dir.path().join("output").display()
    );

    let signals = install_signals()?;
    // The signal passed on to the runs, once one arrived.
    let mut forwarded: Option<(i32, &str)> = None;

    let exe = std::env::current_exe().context("finding this program")?;
    let mut pool = Pool::default();
    let mut view = View::new(to_run);
    let mut finished = 0;
    loop {
        if forwarded.is_none()
            && let Some((signal, name, _)) =
                signals.iter().find(|(_, _, f)| f.load(Ordering::SeqCst))
        {
            forwarded = Some((*signal, name));
            view.say(&format!(
                "stopping: SIG{name} passed on to {} running runs; none is started any more",
                pool.live.len()
            ));
            for run in &pool.live {
                send_signal(run.child.id(), name);
            }
        }
        let mut i = 0;
        while i < pool.live.len() {
            let index = pool.live[i].index;
            let id = state.runs[index].id.clone();
            let waited = pool.live[i].child.try_wait();
            let Some(status) = waited.with_context(|| format!("waiting for run {id}"))? else {
                i += 1;
                continue;
            };
            pool.live.remove(i);
            finished += 1;
            // A run the signal caught before it could handle it is stopped, not failed.
            let stopped = forwarded.is_some_and(|(signal, _)| status.signal() == Some(signal));
            if !status.success() && !stopped {
                state.runs[index].failure = Some(format!("train {status}"));
                dir.write_state(&state)?;
            }
            view.say(&outcome(dir, &id, status, stopped)?);
        }
        while forwarded.is_none() && pool.live.len() < max_parallel {
            let Some(index) = queue.pop_front() else {
                break;
            };
            let entry = &mut state.runs[index];
            let resume = dir.started(&entry.id);
            entry.failure = None;
            dir.write_state(&state)?;
            let child = spawn(&exe, dir, &state.runs[index].id, resume)?;
            pool.live.push(Live { index, child });
        }
        if pool.live.is_empty() && (queue.is_empty() || forwarded.is_some()) {
            break;
        }
        view.show(dir, &state, plan, &pool.live, finished);
        std::thread::sleep(POLL);
    }
    view.finish();

    if let Some((_, name)) = forwarded {
        bail!(
            "sweep stopped by SIG{name}; continue it with: {}",
            dir.resume_command(&state)
        );
    }
    report_failures(dir, &state)
}

/// A flag per signal the sweep passes on to its runs (SIGINT, SIGTERM), set when it arrives.
fn install_signals() -> Result<Vec<(i32, &'static str, Arc<AtomicBool>)>> {
    [(SIGINT, "INT"), (SIGTERM, "TERM")]
        .into_iter()
        .map(|(signal, name)| {
            let flag = Arc::new(AtomicBool::new(false));
            signal_hook::flag::register(signal, flag.clone())
                .context("installing the signal handlers")?;
            Ok((signal, name, flag))
        })
        .collect()
}

/// The sweep's closing line; an error naming each failed run and where its output is.
fn report_failures(dir: &SweepDir, state: &SweepState) -> Result<()> {
    let mut failed = Vec::new();
    for entry in &state.runs {
        if let RunState::Failed(why) = dir.run_state(entry)? {
            failed.push(format!(
                "{} ({why}; see {})",
                entry.id,
                dir.output(&entry.id).display()
            ));
        }
    }
    println!(
        "sweep {}: {} of {} runs done, {} failed; results: pushgrasp sweep summary {}",
        state.name,
        state.runs.len() - failed.len(),
        state.runs.len(),
        failed.len(),
        dir.path().display()
    );
    if !failed.is_empty() {
        bail!("{} runs failed: {}", failed.len(), failed.join(", "));
    }
    Ok(())
}

/// As many runs as the cores hold, each wanting its actors, its learner and its buffer.
fn default_parallel(max_actors: u32) -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    (cores / (max_actors as usize + 2)).max(1)
}

/// Starts `train` for run `id`, its output appended to the run's output file.
fn spawn(exe: &Path, dir: &SweepDir, id: &str, resume: bool) -> Result<Child> {
    let path = dir.output(id);
    let mut output = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))?;
    // A resumed run's output follows its earlier one; a line tells them apart.
    writeln!(
        output,
        "== pushgrasp sweep: {} run {id}",
        if resume { "resuming" } else { "starting" }
    )?;
    let mut command = Command::new(exe);
    command
        .arg("train")
        .arg("--config")
        .arg(dir.run_config(id))
        .arg("--logs")
        .arg(dir.path())
        .args(["--run-id", id]);
    if resume {
        command.arg("--resume");
    }
    command
        .stdin(Stdio::null())
        .stdout(output.try_clone()?)
        .stderr(output);
    command
        .spawn()
        .with_context(|| format!("starting run {id} ({})", exe.display()))
}

/// Passes a signal on with kill(1): the binary has no libc binding of its own, and this
/// happens once per run.
fn send_signal(pid: u32, name: &str) {
    let sent = Command::new("kill")
        .arg(format!("-{name}"))
        .arg(pid.to_string())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status();
    if !sent.is_ok_and(|status| status.success()) {
        eprintln!("could not send SIG{name} to process {pid}");
    }
}

/// One line on how a run ended; `stopped`: by the signal the sweep passed on.
fn outcome(dir: &SweepDir, id: &str, status: ExitStatus, stopped: bool) -> Result<String> {
    let output = dir.output(id);
    if stopped && !status.success() {
        return Ok(format!(
            "run {id} stopped ({status}) before it could stop in order"
        ));
    }
    if !status.success() {
        let error = std::fs::read_to_string(&output)
            .ok()
            .and_then(|text| last_error(&text))
            .unwrap_or_default();
        return Ok(format!(
            "run {id} failed: train {status}: {error} (see {})",
            output.display()
        ));
    }
    Ok(match dir.summary(id)? {
        Some(summary) => format!(
            "run {id} {}: {} episodes, goal grasp success (last 30) {}, {:.0} s",
            if summary.interrupted {
                "interrupted"
            } else {
                "done"
            },
            summary.buffer.episodes,
            rundir::percent(summary.buffer.success_last30),
            summary.wall_s
        ),
        None => format!(
            "run {id} ended without a summary (see {})",
            output.display()
        ),
    })
}

/// The error `train` printed last, on one line: anyhow's `Error: ...` and its causes.
fn last_error(output: &str) -> Option<String> {
    let start = output.rfind("Error: ")?;
    let lines: Vec<&str> = output[start + "Error: ".len()..]
        .lines()
        .map(str::trim)
        .take_while(|line| !line.starts_with("Stack backtrace"))
        .filter(|line| !line.is_empty() && *line != "Caused by:")
        .collect();
    Some(lines.join(": "))
}

/// The sweep's progress: a bar over its runs in a terminal, else a line every 10 s.
struct View {
    bar: Option<ProgressBar>,
    start: Instant,
    last: Instant,
    to_run: usize,
}

impl View {
    fn new(to_run: usize) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = ProgressBar::new(to_run as u64);
            bar.set_style(
                ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:20}] {pos}/{len} runs | {msg}",
                )
                .expect("a valid template")
                .progress_chars("=> "),
            );
            bar
        });
        Self {
            bar,
            start: Instant::now(),
            last: Instant::now(),
            to_run,
        }
    }

    /// Prints a line without breaking the bar.
    fn say(&self, line: &str) {
        match &self.bar {
            Some(bar) => bar.println(line),
            None => println!("{line}"),
        }
    }

    fn show(
        &mut self,
        dir: &SweepDir,
        state: &SweepState,
        plan: &Plan,
        live: &[Live],
        finished: usize,
    ) {
        let every = if self.bar.is_some() {
            REFRESH
        } else {
            PLAIN_EVERY
        };
        if self.last.elapsed() < every {
            return;
        }
        self.last = Instant::now();
        let failed = state
            .runs
            .iter()
            .filter(|run| run.failure.is_some())
            .count();
        let running: Vec<String> = live
            .iter()
            .map(|run| {
                let id = &state.runs[run.index].id;
                let episodes = dir
                    .live_episodes(id)
                    .map_or("?".to_string(), |n| n.to_string());
                format!("{id} {episodes}/{}", plan.runs[run.index].1.episodes)
            })
            .collect();
        let message = format!(
            "{failed} failed | running (episodes): {}",
            running.join(", ")
        );
        match &self.bar {
            Some(bar) => {
                // The message first: setting the position draws the bar.
                bar.set_message(message);
                bar.set_position(finished as u64);
            }
            None => println!(
                "{:7.1} s  runs {finished}/{} ended  {message}",
                self.start.elapsed().as_secs_f64(),
                self.to_run
            ),
        }
    }

    fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_last_error_is_one_line_with_its_causes() {
        let output = "run x: stage 1\nError: first\n\nError: creating x\n\nCaused by:\n    \
                      File exists (os error 17)\n\nStack backtrace:\n   0: main\n";
        assert_eq!(
            last_error(output).as_deref(),
            Some("creating x: File exists (os error 17)")
        );
        assert_eq!(last_error("done: 12 episodes\n"), None);
    }
}
