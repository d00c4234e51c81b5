//! A run read back from its MCAP logs: the files, the episodes in the buffer's order, the
//! actors' steps, the learner's updates and the buffer's counters, and the curves drawn from
//! them.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use messages::EpisodeEnd;
use serde::Serialize;

use rundir::BufferReport;
use rundir::config::RunConfig;
use rundir::record::{ACTOR_STEP, BUFFER_EPISODE, BUFFER_STATS, LEARNER_UPDATE};
use rundir::record::{StepRecord, UpdateRecord};
use rundir::{RunDir, SUCCESS_WINDOW, files_with_extension};

/// Curves are drawn every this many episodes.
const CURVE_EVERY: usize = 10;
/// Learner losses are averaged over windows of at most this many updates (fewer in a short
/// run, so that it still has a curve of about 40 points).
const LOSS_WINDOW: usize = 50;

/// One file of the run.
#[derive(Clone, Debug, Serialize)]
pub struct FileReport {
    pub file: String,
    pub process: Option<String>,
    /// Where the process ran its nets: `cpu`, or `wgpu` and its adapter.
    pub device: Option<String>,
    pub messages: u64,
    /// Seconds from the first to the last message.
    pub span_s: Option<f64>,
    pub recovered: bool,
    pub damage: Vec<String>,
    pub channels: Vec<(String, u64)>,
}

/// An episode, as the buffer took it in.
#[derive(Clone, Debug, Serialize)]
pub struct EpisodeRow {
    /// 1-based, in the order the buffer took the episodes in (the run's episode count).
    pub number: usize,
    pub actor: u32,
    pub incarnation: u32,
    /// The actor's episode id.
    pub episode: u64,
    pub goal: u8,
    pub grasped: Option<u8>,
    pub steps: u32,
    /// Whether its pictures were logged (see `--export`).
    pub pictures: bool,
}

impl EpisodeRow {
    pub fn goal_grasped(&self) -> bool {
        self.grasped == Some(self.goal)
    }

    fn key(&self) -> (u32, u32, u64) {
        (self.actor, self.incarnation, self.episode)
    }
}

/// Everything `inspect` reads from one run directory (or one file).
pub struct Run {
    /// The directory's name (or the file's).
    pub name: String,
    pub files: Vec<FileReport>,
    /// The run's resolved config, from the first file that carries it.
    pub config: Option<RunConfig>,
    pub episodes: Vec<EpisodeRow>,
    /// Every step the actors logged, each with the file it came from.
    pub steps: Vec<(PathBuf, StepRecord)>,
    pub updates: Vec<UpdateRecord>,
    /// The buffer's counters as it logged them.
    pub buffer: Vec<BufferReport>,
}

/// The stage runs of a pipeline directory (`stage<N>/` with MCAP logs), in stage order; empty
/// for any other path.
pub fn pipeline_stages(path: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(path) else {
        return Vec::new();
    };
    let mut stages: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_dir()
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .and_then(|n| n.strip_prefix("stage"))
                    .is_some_and(|n| n.parse::<u8>().is_ok())
                && files_with_extension(p, "mcap").is_ok()
        })
        .collect();
    stages.sort();
    stages
}

/// The `.mcap` files of a run directory, or the one file given. A run across hosts has its
/// joined hosts' directories under `hosts/` (gathered there, or written there on a shared
/// filesystem): their files are the run's too. Each log's segments follow its own file, in
/// order, so its messages are read in the order they were logged.
pub fn mcap_files(path: &Path) -> Result<Vec<PathBuf>> {
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files = files_with_extension(path, "mcap")?;
    let hosts = RunDir::new(path).hosts();
    if let Ok(entries) = std::fs::read_dir(&hosts) {
        let mut dirs: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
        dirs.sort();
        for dir in dirs.iter().filter(|d| d.is_dir()) {
            files.extend(files_with_extension(dir, "mcap").unwrap_or_default());
        }
    }
    let later: HashSet<PathBuf> = files
        .iter()
        .flat_map(|file| mcaplog::segments(file).into_iter().skip(1))
        .collect();
    Ok(files
        .iter()
        .filter(|file| !later.contains(*file))
        .flat_map(|file| mcaplog::segments(file))
        .collect())
}

/// The JSON messages on `topic` decoded as `T`; an error names the file and the topic.
fn records<T: serde::de::DeserializeOwned>(file: &Path, topic: &str) -> Result<Vec<T>> {
    mcaplog::json_messages(file, topic)?
        .into_iter()
        .map(|v| {
            serde_json::from_value(v).with_context(|| {
                format!("{}: a {topic} message is not as expected", file.display())
            })
        })
        .collect()
}

impl Run {
    pub fn read(path: &Path) -> Result<Run> {
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into(),
        );
        let mut run = Run {
            name,
            files: Vec::new(),
            config: None,
            episodes: Vec::new(),
            steps: Vec::new(),
            updates: Vec::new(),
            buffer: Vec::new(),
        };
        let mut ends: Vec<EpisodeEnd> = Vec::new();
        for file in mcap_files(path)? {
            let summary = mcaplog::read_summary(&file)?;
            // Each topic read is a pass over the file: only where the topic has messages.
            let has = |topic: &str| summary.messages_on(topic) > 0;
            if has(ACTOR_STEP) {
                let steps = records::<StepRecord>(&file, ACTOR_STEP)?;
                run.steps
                    .extend(steps.into_iter().map(|s| (file.clone(), s)));
            }
            if has(BUFFER_EPISODE) {
                // Trial grasps are experience, not episodes.
                ends.extend(
                    records::<EpisodeEnd>(&file, BUFFER_EPISODE)?
                        .into_iter()
                        .filter(|end| !end.trial),
                );
            }
            if has(BUFFER_STATS) {
                run.buffer
                    .extend(records::<BufferReport>(&file, BUFFER_STATS)?);
            }
            if has(LEARNER_UPDATE) {
                run.updates
                    .extend(records::<UpdateRecord>(&file, LEARNER_UPDATE)?);
            }
            if run.config.is_none()
                && let Some(toml) = summary.metadata("config").and_then(|c| c.get("toml"))
            {
                let config = toml::from_str(toml)
                    .with_context(|| format!("{}: its config record", file.display()))?;
                run.config = Some(config);
            }
            run.files.push(FileReport {
                file: file.display().to_string(),
                process: summary
                    .metadata(mcaplog::PROCESS_METADATA)
                    .and_then(|p| p.get("name").cloned()),
                device: summary.metadata("device").map(|d| {
                    let on = d.get("backend").map_or("?", String::as_str);
                    match d.get("adapter") {
                        Some(adapter) => format!("{on}: {adapter}"),
                        None => on.to_string(),
                    }
                }),
                messages: summary.messages,
                span_s: summary.time_span_ns.map(|(a, b)| (b - a) as f64 * 1e-9),
                recovered: summary.recovered,
                damage: summary.damage.clone(),
                channels: summary
                    .channels
                    .iter()
                    .map(|c| (c.topic.clone(), c.messages))
                    .collect(),
            });
        }
        let with_pictures: HashSet<(u32, u32, u64)> = run
            .steps
            .iter()
            .filter(|(_, s)| s.pictures_ns.is_some())
            .map(|(_, s)| (s.actor, s.incarnation, s.episode))
            .collect();
        run.episodes = ends
            .into_iter()
            .enumerate()
            .map(|(i, end)| {
                let key = (end.origin.actor, end.origin.incarnation, end.episode);
                EpisodeRow {
                    number: i + 1,
                    actor: key.0,
                    incarnation: key.1,
                    episode: key.2,
                    goal: end.goal,
                    grasped: end.grasped,
                    steps: end.steps,
                    pictures: with_pictures.contains(&key),
                }
            })
            .collect();
        Ok(run)
    }

    /// The steps of episode `number` (1-based, as numbered in the episode table).
    pub fn episode(&self, number: usize) -> Result<(&EpisodeRow, Vec<&(PathBuf, StepRecord)>)> {
        let Some(row) = number.checked_sub(1).and_then(|i| self.episodes.get(i)) else {
            bail!(
                "{}: no episode {number}; the run has episodes 1 to {}",
                self.name,
                self.episodes.len()
            );
        };
        let mut steps: Vec<_> = self
            .steps
            .iter()
            .filter(|(_, s)| (s.actor, s.incarnation, s.episode) == row.key())
            .collect();
        steps.sort_by_key(|(_, s)| s.step);
        Ok((row, steps))
    }

    /// The actions (steps) the run had taken when each episode ended: index i holds the
    /// count after episode i + 1.
    pub fn actions_by_episode(&self) -> Vec<u64> {
        self.episodes
            .iter()
            .scan(0u64, |total, e| {
                *total += u64::from(e.steps);
                Some(*total)
            })
            .collect()
    }

    /// Goal grasp success over the last 30 episodes, every 10 episodes (and at the last).
    pub fn success_curve(&self) -> Vec<(u64, f64)> {
        let outcomes: Vec<bool> = self.episodes.iter().map(EpisodeRow::goal_grasped).collect();
        sampled(outcomes.len(), |lo, hi| {
            let window = &outcomes[lo..hi];
            Some(window.iter().filter(|&&g| g).count() as f64 / window.len() as f64)
        })
    }

    /// The mean predicted Q of the goal grasps among the last 30 episodes, every 10 episodes:
    /// the paper trains stage 1 until it is stably above Q*.
    pub fn goal_grasp_q_curve(&self) -> Vec<(u64, f64)> {
        let number: HashMap<(u32, u32, u64), usize> =
            self.episodes.iter().map(|e| (e.key(), e.number)).collect();
        let mut q_by_episode: Vec<Option<f32>> = vec![None; self.episodes.len()];
        for (_, s) in &self.steps {
            if s.primitive == "grasp"
                && s.grasped == Some(s.goal)
                && let Some(&n) = number.get(&(s.actor, s.incarnation, s.episode))
            {
                q_by_episode[n - 1] = Some(s.predicted_q);
            }
        }
        sampled(q_by_episode.len(), |lo, hi| {
            let qs: Vec<f64> = q_by_episode[lo..hi]
                .iter()
                .flatten()
                .map(|&q| q.into())
                .collect();
            (!qs.is_empty()).then(|| qs.iter().sum::<f64>() / qs.len() as f64)
        })
    }

    /// The share of the buffer's stored transitions that are relabelled copies, against the
    /// episodes it had taken in.
    pub fn relabelled_curve(&self) -> Vec<(u64, f64)> {
        let mut points: Vec<(u64, f64)> = Vec::new();
        for r in self.buffer.iter().filter(|r| r.inserted > 0) {
            let point = (r.episodes, r.relabelled as f64 / r.inserted as f64);
            match points.last_mut() {
                Some(last) if last.0 == point.0 => *last = point,
                _ => points.push(point),
            }
        }
        points
    }

    /// The learner's loss per primitive, averaged over windows of up to 50 updates.
    pub fn loss_curves(&self) -> Vec<(String, Vec<(u64, f64)>)> {
        let mut primitives: Vec<&str> = self.updates.iter().map(|u| u.primitive.as_str()).collect();
        primitives.sort();
        primitives.dedup();
        primitives
            .into_iter()
            .map(|primitive| {
                let updates: Vec<&UpdateRecord> = self
                    .updates
                    .iter()
                    .filter(|u| u.primitive == primitive)
                    .collect();
                let window = (updates.len() / 40).clamp(1, LOSS_WINDOW);
                let points = updates
                    .chunks(window)
                    .map(|w| {
                        let mean =
                            w.iter().map(|u| f64::from(u.loss)).sum::<f64>() / w.len() as f64;
                        (w.last().expect("chunks are not empty").updates, mean)
                    })
                    .collect();
                (primitive.to_string(), points)
            })
            .collect()
    }
}

/// `f(lo, hi)` over the window of the last 30 of the first `i` items, for every tenth `i`
/// and the last; windows where `f` has no value are left out.
fn sampled(n: usize, f: impl Fn(usize, usize) -> Option<f64>) -> Vec<(u64, f64)> {
    (1..=n)
        .filter(|i| i % CURVE_EVERY == 0 || *i == n)
        .filter_map(|i| f(i.saturating_sub(SUCCESS_WINDOW), i).map(|v| (i as u64, v)))
        .collect()
}
