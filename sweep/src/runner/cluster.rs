//! `pushgrasp cluster`: one training run across the nodes of one Slurm job. The batch script
//! starts the central role (`train --listen`) on the job's first node and `join` on each of
//! the others through `srun`; they meet at the first node's address (its `NodeAddr` as Slurm
//! knows it), and the joined hosts read the run's secret from the run directory on the
//! shared filesystem, where each also writes its own directory (`hosts/<node>/`).

use std::path::PathBuf;

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;

use super::submit::sbatch;
use crate::bash_quote;

#[derive(Args)]
pub struct ClusterArgs {
    /// The run's config (TOML).
    #[arg(long, default_value = "configs/stage1.toml")]
    config: PathBuf,
    /// The run's id; its directory is `<logs>/<run id>/` on the shared filesystem.
    #[arg(long)]
    run_id: String,
    /// Nodes of the job: the first runs the buffer, the learner and --central-actors; each
    /// other runs --actors-per-node actors.
    #[arg(long)]
    nodes: u32,
    #[arg(long)]
    actors_per_node: u32,
    #[arg(long, default_value_t = 0)]
    central_actors: u32,
    /// The port the central role listens on.
    #[arg(long, default_value_t = 7447)]
    port: u16,
    /// Where run directories go: a directory every node sees.
    #[arg(long, default_value = "logs")]
    logs: PathBuf,
    /// Slurm's partition and time limit.
    #[arg(long)]
    partition: Option<String>,
    #[arg(long)]
    time: Option<String>,
    /// Submit the script with sbatch (else it is written only).
    #[arg(long)]
    submit: bool,
}

/// Writes the batch script to `<logs>/<run id>.cluster.sbatch` and, with `--submit`,
/// submits it.
pub fn run(args: &ClusterArgs) -> Result<()> {
    if args.nodes < 2 || args.actors_per_node == 0 {
        bail!("--nodes must be at least 2 and --actors-per-node at least 1");
    }
    // Every node starts in the directory sbatch ran in: absolute paths.
    let absolute = |path: &PathBuf| {
        std::path::absolute(path).with_context(|| format!("resolving {}", path.display()))
    };
    let (config, logs) = (absolute(&args.config)?, absolute(&args.logs)?);
    std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
    let exe = std::env::current_exe().context("finding this program")?;
    let word = |path: &std::path::Path| {
        path.to_str()
            .map(bash_quote)
            .ok_or_else(|| anyhow!("{} is not UTF-8", path.display()))
    };
    let script = cluster_script(&Script {
        args,
        exe: word(&exe)?,
        config: word(&config)?,
        logs: word(&logs)?,
        output: logs.join(format!("{}.cluster-%j.out", args.run_id)),
    })?;
    let path = logs.join(format!("{}.cluster.sbatch", args.run_id));
    std::fs::write(&path, script).with_context(|| format!("writing {}", path.display()))?;
    if !args.submit {
        println!(
            "wrote {}: submit it with `sbatch {}` (or this command with --submit)",
            path.display(),
            path.display()
        );
        return Ok(());
    }
    let job = sbatch(&path)?;
    println!(
        "submitted job {job}: run {} on {} nodes, its output in {}",
        args.run_id,
        args.nodes,
        logs.join(format!("{}.cluster-{job}.out", args.run_id))
            .display()
    );
    Ok(())
}

/// What the script is made of, quoted for bash.
struct Script<'a> {
    args: &'a ClusterArgs,
    exe: String,
    config: String,
    logs: String,
    output: PathBuf,
}

fn cluster_script(s: &Script<'_>) -> Result<String> {
    let args = s.args;
    let output = s
        .output
        .to_str()
        .filter(|o| !o.contains(['\n', '\r', '\\', '"']))
        .ok_or_else(|| anyhow!("{} cannot be an #SBATCH --output", s.output.display()))?;
    let mut script = String::from("#!/bin/bash\n");
    script.push_str(&format!("#SBATCH --job-name=pushgrasp-{}\n", args.run_id));
    script.push_str(&format!("#SBATCH --nodes={}\n", args.nodes));
    script.push_str("#SBATCH --ntasks-per-node=1\n");
    script.push_str(&format!("#SBATCH --output=\"{output}\"\n"));
    if let Some(partition) = &args.partition {
        script.push_str(&format!("#SBATCH --partition={partition}\n"));
    }
    if let Some(time) = &args.time {
        script.push_str(&format!("#SBATCH --time={time}\n"));
    }
    let remote = (args.nodes - 1) * args.actors_per_node;
    script.push_str(&format!(
        r#"# Run {run}: the central role on the first node, {actors} actors on each of the others.
set -euo pipefail
RUN={run}
NODES=($(scontrol show hostnames "$SLURM_JOB_NODELIST"))
CENTRAL=${{NODES[0]}}
ADDRESS=$(scontrol show node "$CENTRAL" | sed -n 's/.*NodeAddr=\([^ ]*\).*/\1/p')
SECRET={logs}/"$RUN"/run.secret

srun --nodes=1 --ntasks=1 --nodelist="$CENTRAL" {exe} train --config {config} --logs {logs} \
    --run-id "$RUN" --listen tcp/0.0.0.0:{port} --actors {central} --remote-actors {remote} &
CENTRAL_STEP=$!
# The central role writes the secret before it listens; the hosts keep asking until it does.
until [ -e "$SECRET" ]; do
    kill -0 "$CENTRAL_STEP" 2>/dev/null || {{ wait "$CENTRAL_STEP"; exit $?; }}
    sleep 1
done
sleep 2
for NODE in "${{NODES[@]:1}}"; do
    srun --nodes=1 --ntasks=1 --nodelist="$NODE" {exe} join "tcp/$ADDRESS:{port}" \
        --run-id "$RUN" --secret-file "$SECRET" --actors {actors} --logs {logs} \
        --host-name "$NODE" &
done
STATUS=0
wait "$CENTRAL_STEP" || STATUS=$?
# The hosts stop with the run (or, with the central role gone, after their give-up time).
wait || true
exit $STATUS
"#,
        run = bash_quote(&args.run_id),
        actors = args.actors_per_node,
        logs = s.logs,
        exe = s.exe,
        config = s.config,
        port = args.port,
        central = args.central_actors,
    ));
    Ok(script)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_script_starts_the_central_role_first_and_joins_the_others() {
        let args = ClusterArgs {
            config: "c.toml".into(),
            run_id: "big".into(),
            nodes: 3,
            actors_per_node: 4,
            central_actors: 0,
            port: 7447,
            logs: "/shared/logs".into(),
            partition: Some("gpu".into()),
            time: None,
            submit: false,
        };
        let script = cluster_script(&Script {
            args: &args,
            exe: "'/bin/pushgrasp'".into(),
            config: "'/c.toml'".into(),
            logs: "'/shared/logs'".into(),
            output: "/shared/logs/big.cluster-%j.out".into(),
        })
        .unwrap();
        assert!(script.contains("#SBATCH --nodes=3\n#SBATCH --ntasks-per-node=1\n"));
        assert!(script.contains("#SBATCH --partition=gpu\n"));
        assert!(script.contains("--listen tcp/0.0.0.0:7447 --actors 0 --remote-actors 8"));
        assert!(script.contains("join \"tcp/$ADDRESS:7447\""));
        assert!(script.find("train").unwrap() < script.find(" join ").unwrap());
    }
}
