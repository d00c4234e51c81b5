//! `pushgrasp scene`: render scenes to PNGs, convert arrangement files, and try every direct
//! grasp of an arrangement's goal; and `pushgrasp episode`, a scripted episode on a random
//! scene with what the robot saw written out.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use sim::{Arrangement, Camera, OriginalOptions, SimConfig, Tabletop};

mod episode;
mod grasp_map;
mod pictures;
mod rows;

pub use episode::{EpisodeArgs, run as episode};
use rows::RowArgs;

#[derive(Subcommand)]
pub enum SceneCommand {
    /// Write PNGs of the colour, height and id heightmaps of a random scene or an arrangement.
    Render(RenderArgs),
    /// Convert an original test-case file to our TOML arrangement format (on stdout).
    Convert(ConvertArgs),
    /// Try every direct grasp of an arrangement's goal in the simulator: how many succeed.
    Grasps(grasp_map::GraspsArgs),
}

/// Where a scene comes from: random drops or an arrangement file.
#[derive(Args)]
pub struct SceneSource {
    /// Number of objects to drop at random.
    #[arg(long, default_value_t = 10, conflicts_with = "arrangement")]
    pub objects: usize,
    /// Seed of the random scene.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub rows: RowArgs,
    /// An arrangement file (original `.txt` format or our `.toml`) instead of random drops.
    #[arg(long, conflicts_with_all = ["row", "lines"])]
    pub arrangement: Option<PathBuf>,
    /// Add the authors' +0.1 m y offset when reading an original-format file.
    #[arg(long)]
    pub y_offset: bool,
    /// Heightmap pixel size in metres (0.002 -> 224 x 224, 0.004 -> 112 x 112).
    #[arg(long, default_value_t = 0.002)]
    pub pixel_size: f32,
}

impl SceneSource {
    /// Builds the scene, settled, and a one-line description of it.
    pub fn build(&self) -> Result<(Tabletop, String)> {
        let config = SimConfig::with_pixel_size(self.pixel_size);
        match &self.arrangement {
            Some(path) => {
                let options = OriginalOptions {
                    y_offset: self.y_offset,
                };
                let arrangement = Arrangement::read(path, &options)?;
                let mut tabletop = Tabletop::from_arrangement(&config, &arrangement)?;
                let settle = tabletop.settle();
                let description = format!(
                    "arrangement {} ({} objects, goal {:?}, settled in {} steps, left the table: {:?})",
                    path.display(),
                    arrangement.objects.len(),
                    arrangement.goal,
                    settle.steps,
                    settle.removed
                );
                Ok((tabletop, description))
            }
            None => {
                let (tabletop, report) =
                    Tabletop::random_with_rows(&config, self.objects, self.rows.rows(), self.seed)?;
                let description = format!(
                    "random scene seed {} ({} dropped, settled in {} steps, at rest: {}, left the table: {:?})",
                    self.seed,
                    report.dropped.len(),
                    report.settle.steps,
                    report.settle.at_rest,
                    report.settle.removed
                );
                Ok((tabletop, description))
            }
        }
    }
}

#[derive(Args)]
pub struct RenderArgs {
    #[command(flatten)]
    source: SceneSource,
    /// Directory the PNGs go to.
    #[arg(long, default_value = "logs/render")]
    out: PathBuf,
}

#[derive(Args)]
pub struct ConvertArgs {
    /// The original-format file.
    file: PathBuf,
    /// The goal's slot (line index from 0, as the paper numbers them), for files that do not
    /// name their goal.
    #[arg(long)]
    goal_slot: Option<u8>,
    /// Add the authors' +0.1 m y offset.
    #[arg(long)]
    y_offset: bool,
    /// Name written into the file (default: the file's stem).
    #[arg(long)]
    name: Option<String>,
}

pub fn run(command: SceneCommand) -> Result<()> {
    match command {
        SceneCommand::Render(args) => render(&args),
        SceneCommand::Convert(args) => convert(&args),
        SceneCommand::Grasps(args) => grasp_map::run(&args),
    }
}

fn render(args: &RenderArgs) -> Result<()> {
    let (tabletop, description) = args.source.build()?;
    let maps = Camera::new(tabletop.grid()).render(&tabletop);
    let stem = match &args.source.arrangement {
        Some(path) => path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "arrangement".into()),
        None => format!(
            "random-{}{}-seed{}",
            args.source.objects,
            args.source.rows.label(),
            args.source.seed
        ),
    };
    println!("{description}");
    for path in pictures::write_heightmaps(&maps, &args.out, &stem)? {
        println!("wrote {}", path.display());
    }
    Ok(())
}

fn convert(args: &ConvertArgs) -> Result<()> {
    let options = OriginalOptions {
        y_offset: args.y_offset,
    };
    let mut arrangement = Arrangement::read(&args.file, &options)?;
    if let Some(name) = &args.name {
        arrangement.name = Some(name.clone());
    }
    if let Some(slot) = args.goal_slot {
        if let Some(goal) = arrangement.goal {
            bail!(
                "{}: the file names its goal (object {goal}, slot {}); --goal-slot is for files that do not",
                args.file.display(),
                goal - 1
            );
        }
        let goal = slot
            .checked_add(1)
            .filter(|goal| arrangement.objects.iter().any(|o| o.id == *goal));
        let Some(goal) = goal else {
            bail!(
                "{}: goal slot {slot} is not an object on the table",
                args.file.display()
            );
        };
        arrangement.goal = Some(goal);
    }
    println!(
        "# Converted from {} by `pushgrasp scene convert`.\n# Ids are the original slots + 1; positions in metres, angles in radians (x, y, z of the moving frame);\n# colours as the file gives them, else the slot colours of our random scenes.\n{}",
        args.file.file_name().unwrap_or_default().to_string_lossy(),
        arrangement.to_toml()
    );
    Ok(())
}
