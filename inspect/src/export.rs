//! `inspect --episode K --export DIR`: one episode's pictures as PNG files and its steps as
//! JSON, for people to look at what the robot saw and what it chose.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use image::{DynamicImage, GrayImage, ImageBuffer, Luma, RgbImage};
use mcaplog::RawImage;

use super::run::Run;
use rundir::record::ACTOR_PICTURES;

/// Writes `step-<s>-<picture>.png` for each step of episode `number` whose pictures were
/// logged, and `episode.json` (the episode and its steps); returns the files written.
pub fn export_episode(run: &Run, number: usize, dir: &Path) -> Result<Vec<PathBuf>> {
    let (row, steps) = run.episode(number)?;
    if !row.pictures {
        let with: Vec<String> = run
            .episodes
            .iter()
            .filter(|e| e.pictures)
            .map(|e| e.number.to_string())
            .take(20)
            .collect();
        bail!(
            "{}: episode {number} has no pictures (an actor logs them every \
             logging.image_every episodes); episodes with pictures: {}",
            run.name,
            if with.is_empty() {
                "none".to_string()
            } else {
                with.join(", ")
            }
        );
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut written = Vec::new();
    // Every picture of the episode is in its actor's file, stamped with its step's time.
    let file = &steps[0].0;
    let step_at: BTreeMap<u64, u32> = steps
        .iter()
        .filter_map(|(_, s)| s.pictures_ns.map(|t| (t, s.step)))
        .collect();
    for topic in ACTOR_PICTURES {
        for (time, raw) in mcaplog::proto_messages::<RawImage>(file, topic)? {
            if let Some(step) = step_at.get(&time) {
                let kind = topic.rsplit('/').next().expect("topics have a name");
                let path = dir.join(format!("step-{step}-{kind}.png"));
                to_image(&raw)
                    .with_context(|| format!("{}: a {topic} image", file.display()))?
                    .save(&path)
                    .with_context(|| format!("writing {}", path.display()))?;
                written.push(path);
            }
        }
    }
    let path = dir.join("episode.json");
    let json = serde_json::json!({
        "episode": row,
        "steps": steps.iter().map(|(_, s)| s).collect::<Vec<_>>(),
    });
    std::fs::write(&path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("writing {}", path.display()))?;
    written.push(path);
    Ok(written)
}

/// A logged image as a PNG-able image: rgb8, mono8 or mono16 (little-endian).
fn to_image(raw: &RawImage) -> Result<DynamicImage> {
    let (w, h) = (raw.width, raw.height);
    let size_error = || anyhow::anyhow!("{w}x{h} {} with {} bytes", raw.encoding, raw.data.len());
    Ok(match raw.encoding.as_str() {
        "rgb8" => RgbImage::from_raw(w, h, raw.data.clone())
            .ok_or_else(size_error)?
            .into(),
        "mono8" => GrayImage::from_raw(w, h, raw.data.clone())
            .ok_or_else(size_error)?
            .into(),
        "mono16" => {
            let values: Vec<u16> = raw
                .data
                .chunks_exact(2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]))
                .collect();
            ImageBuffer::<Luma<u16>, _>::from_raw(w, h, values)
                .ok_or_else(size_error)?
                .into()
        }
        other => bail!("encoding {other} is not one an actor logs"),
    })
}
