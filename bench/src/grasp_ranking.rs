//! `pushgrasp bench grasp-ranking`: whether a grasp net tells the grasps that pick its goal
//! out of a packed cluster from those that don't. Every other pixel of the goal at 8 jaw
//! angles is tried in the simulator on jittered copies of the scene; the net's Q of each is
//! set against those outcomes (AUC), and its top grasps against grasps at random.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use clap::builder::RangedU64ValueParser;

/// The AUC a grasp net should reach (the goal of learning to rank grasps in clutter).
const AUC_TARGET: f64 = 0.85;

#[derive(Args)]
pub struct GraspRankingArgs {
    /// The checkpoint whose grasp net is scored (a run's `checkpoint/`).
    #[arg(long)]
    checkpoint: PathBuf,
    /// The config it was trained with (default: `config.toml` in its run directory).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Packed clusters to score on.
    #[arg(long, default_value_t = 12, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    scenes: usize,
    /// Jittered copies each grasp is tried on (a grasp "always" picks the goal when it does
    /// on every copy, "never" when on none).
    #[arg(long, default_value_t = 4, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    jitters: usize,
    /// The scenes and jitters derive from this seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

pub fn bench_grasp_ranking(args: &GraspRankingArgs) -> Result<()> {
    let ranking = scene_tools::grasp_ranking(
        args.checkpoint.clone(),
        args.config.clone(),
        args.scenes,
        args.jitters,
        args.seed,
    )?;
    if args.json {
        let mut figures = serde_json::to_value(&ranking)?;
        figures["auc_target"] = AUC_TARGET.into();
        println!("{figures}");
        return Ok(());
    }
    let percent = |share: f64| format!("{:.1}%", 100.0 * share);
    let auc = ranking
        .auc
        .map_or("- (no scene had both kinds)".into(), |a| format!("{a:.2}"));
    println!(
        "grasp ranking on {} packed clusters ({} copies per grasp)",
        ranking.scenes, args.jitters
    );
    println!("  AUC (always vs never picks the goal)  {auc}   target >= {AUC_TARGET}");
    println!(
        "  the net's best grasp                  {}",
        percent(ranking.top1_success)
    );
    println!(
        "  the net's top {}                       {}",
        ranking.top_k,
        percent(ranking.top_k_success)
    );
    println!(
        "  a grasp at random on the goal         {}",
        percent(ranking.random_success)
    );
    Ok(())
}
