//! PNG pictures of heightmaps, for people to look at.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use image::{GrayImage, RgbImage};
use sim::Heightmaps;

/// Heights are drawn from black (table) to white at this height (metres).
pub const HEIGHT_SCALE_TOP: f32 = 0.15;

/// Writes `<stem>-colour.png`, `<stem>-height.png` and `<stem>-ids.png` into `dir` and
/// returns their paths.
pub fn write_heightmaps(maps: &Heightmaps, dir: &Path, stem: &str) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let side = maps.side() as u32;
    let colour = RgbImage::from_fn(side, side, |x, y| {
        image::Rgb(maps.colour[maps.index(y as usize, x as usize)])
    });
    let height = GrayImage::from_fn(side, side, |x, y| {
        let h = maps.height[maps.index(y as usize, x as usize)];
        image::Luma([(h / HEIGHT_SCALE_TOP * 255.0).clamp(0.0, 255.0) as u8])
    });
    let ids = RgbImage::from_fn(side, side, |x, y| {
        image::Rgb(id_colour(maps.ids[maps.index(y as usize, x as usize)]))
    });
    let paths: Vec<PathBuf> = ["colour", "height", "ids"]
        .iter()
        .map(|kind| dir.join(format!("{stem}-{kind}.png")))
        .collect();
    colour
        .save(&paths[0])
        .with_context(|| format!("writing {}", paths[0].display()))?;
    height
        .save(&paths[1])
        .with_context(|| format!("writing {}", paths[1].display()))?;
    ids.save(&paths[2])
        .with_context(|| format!("writing {}", paths[2].display()))?;
    Ok(paths)
}

/// A distinct false colour per object id (black for the table).
fn id_colour(id: u8) -> [u8; 3] {
    if id == 0 {
        return [0, 0, 0];
    }
    let hue = (id as f32 * 0.618_034).fract() * 6.0;
    let x = 1.0 - (hue % 2.0 - 1.0).abs();
    let (r, g, b) = match hue as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    [r, g, b].map(|c: f32| (55.0 + 200.0 * c) as u8)
}
