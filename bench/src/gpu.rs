//! `pushgrasp bench gpu`: every GPU figure in one go, for the few minutes a GPU host is at
//! hand. Each benchmark runs as a process of its own (this binary, so the CubeCL settings
//! read at a device's start can differ between them) within its share of one time budget,
//! most wanted first; every figure goes into one JSON file, written again after each
//! benchmark, so a host taken back mid-way leaves what was measured.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Args;
use serde_json::{Map, Value, json};

#[derive(Args)]
pub struct GpuBenchArgs {
    /// The JSON file every figure goes into.
    #[arg(long, default_value = "gpu-figures.json")]
    out: PathBuf,
    /// Seconds for all the benchmarks together; one that would run past it is stopped, and
    /// those after it are skipped.
    #[arg(long, default_value_t = 450)]
    budget_s: u64,
    /// Heightmap side of the shipped and the stage nets (pixels).
    #[arg(long, default_value_t = 112)]
    side: usize,
    /// Heightmap side of the paper-size nets.
    #[arg(long, default_value_t = 224)]
    paper_side: usize,
    /// Repetitions of each timed figure (the paper-size nets' half as many, at least one).
    #[arg(long, default_value_t = 10)]
    reps: usize,
    /// The stage nets' run config.
    #[arg(long, default_value = "configs/stage1.toml")]
    stage_config: PathBuf,
    /// The paper-size nets' run config.
    #[arg(long, default_value = "configs/paper-size.toml")]
    paper_config: PathBuf,
    /// Episodes of each `bench e2e` run (its CPU learner's and its GPU learner's).
    #[arg(long, default_value_t = 40)]
    e2e_episodes: u64,
    /// The `bench e2e` runs' environment counts.
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 4])]
    e2e_environments: Vec<u32>,
    /// The values of `CUBECL_WGPU_MAX_TASKS` (operations CubeCL batches into one submission;
    /// 32 unset) under which the shipped nets' learner bench runs again.
    #[arg(long, value_delimiter = ',', default_values_t = [8usize, 128])]
    max_tasks: Vec<usize>,
    /// Side of the matrices whose product gives each learner bench's matmul peak.
    #[arg(long, default_value_t = 1024)]
    peak_side: usize,
}

/// One benchmark: its name in the file, its arguments to this binary, its environment.
struct Bench {
    name: String,
    args: Vec<String>,
    env: Vec<(&'static str, String)>,
}

pub fn bench_gpu(args: &GpuBenchArgs) -> Result<()> {
    let budget = Duration::from_secs(args.budget_s);
    let start = Instant::now();
    let mut figures = Map::new();
    let mut runs = Vec::new();
    for bench in benches(args) {
        let left = budget.saturating_sub(start.elapsed());
        let (status, seconds) = if left.is_zero() {
            ("skipped: the budget was spent".to_string(), 0.0)
        } else {
            let began = Instant::now();
            let status = match run(&bench, left)? {
                Outcome::Figures(value) => {
                    figures.insert(bench.name.clone(), value);
                    "done".to_string()
                }
                Outcome::Failed(why) => why,
            };
            (status, began.elapsed().as_secs_f64())
        };
        eprintln!("bench gpu: {} {status} ({seconds:.0} s)", bench.name);
        runs.push(json!({
            "name": bench.name,
            "command": bench.args.join(" "),
            "env": bench.env.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>(),
            "status": status,
            "seconds": seconds,
        }));
        let mut file = figures.clone();
        file.insert("runs".into(), Value::Array(runs.clone()));
        rundir::write_json(&args.out, &Value::Object(file))?;
    }
    println!("{}", args.out.display());
    Ok(())
}

/// The benchmarks, most wanted first: the learner's at the shipped, the stage and the
/// paper-size nets, a real run with each learner, then the shipped nets under each
/// `CUBECL_WGPU_MAX_TASKS`.
fn benches(args: &GpuBenchArgs) -> Vec<Bench> {
    let learner = |sides: usize, reps: usize, config: Option<&Path>| {
        let mut a = [
            "bench",
            "learner",
            "--backend",
            "wgpu",
            "--json",
            "--kernel-names",
        ]
        .map(String::from)
        .to_vec();
        for (arg, value) in [
            ("--sides", sides),
            ("--reps", reps),
            ("--peak-side", args.peak_side),
        ] {
            a.extend([arg.to_string(), value.to_string()]);
        }
        if let Some(config) = config {
            a.extend(["--config".into(), config.display().to_string()]);
        }
        a
    };
    let bench = |name: &str, args: Vec<String>| Bench {
        name: name.into(),
        args,
        env: Vec::new(),
    };
    let environments = args
        .e2e_environments
        .iter()
        .map(u32::to_string)
        .collect::<Vec<_>>()
        .join(",");
    let (stage_config, episodes) = (
        args.stage_config.display().to_string(),
        args.e2e_episodes.to_string(),
    );
    let mut benches = vec![
        bench("learner", learner(args.side, args.reps, None)),
        bench(
            "learner_stage",
            learner(args.side, args.reps, Some(args.stage_config.as_path())),
        ),
        bench(
            "learner_paper_size",
            learner(
                args.paper_side,
                (args.reps / 2).max(1),
                Some(args.paper_config.as_path()),
            ),
        ),
        bench(
            "e2e",
            [
                "bench",
                "e2e",
                "--learners",
                "cpu,wgpu",
                "--json",
                "--config",
                stage_config.as_str(),
                "--episodes",
                episodes.as_str(),
                "--environments",
                environments.as_str(),
            ]
            .map(String::from)
            .to_vec(),
        ),
    ];
    benches.extend(args.max_tasks.iter().map(|&tasks| Bench {
        name: format!("learner_max_tasks_{tasks}"),
        args: learner(args.side, args.reps, None),
        env: vec![("CUBECL_WGPU_MAX_TASKS", tasks.to_string())],
    }));
    benches
}

enum Outcome {
    /// The benchmark's figures (its last line of output, one JSON object).
    Figures(Value),
    /// Why there are none.
    Failed(String),
}

/// Runs one benchmark as a child of this binary, stopped at `deadline` from now.
fn run(bench: &Bench, deadline: Duration) -> Result<Outcome> {
    let mut child = Command::new(std::env::current_exe()?)
        .args(&bench.args)
        .envs(bench.env.iter().map(|(k, v)| (k, v)))
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .with_context(|| format!("starting {}", bench.name))?;
    let mut stdout = child.stdout.take().expect("stdout is piped");
    let reader = std::thread::spawn(move || {
        let mut out = String::new();
        stdout.read_to_string(&mut out).map(|_| out)
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break Some(status);
        }
        if start.elapsed() >= deadline {
            child.kill()?;
            child.wait()?;
            break None;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let out = reader.join().expect("the reader thread does not panic")?;
    Ok(match status {
        None => Outcome::Failed(format!(
            "stopped at the budget's end after {:.0} s",
            deadline.as_secs_f64()
        )),
        Some(status) if !status.success() => Outcome::Failed(format!("failed: {status}")),
        Some(_) => match out.lines().last().map(serde_json::from_str::<Value>) {
            Some(Ok(value)) => Outcome::Figures(value),
            _ => Outcome::Failed(format!("no JSON figures in its output: {out:?}")),
        },
    })
}
