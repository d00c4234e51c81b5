//! A run's files as JSON, written whole or not at all; the files of a kind in a folder; and
//! the arrangement files a test names.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::Serialize;
use sim::Arrangement;

/// Writes JSON through a temporary file, so a reader never sees half of it.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_vec_pretty(value)?)
        .with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))
}

/// Reads what [`write_json`] wrote.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_slice(&bytes).with_context(|| format!("reading {}", path.display()))
}

/// The files in `dir` whose names end in `.<extension>`, sorted; none is an error naming the
/// directory.
pub fn files_with_extension(dir: &Path, extension: &str) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == extension))
        .collect();
    files.sort();
    if files.is_empty() {
        anyhow::bail!("{}: no .{extension} files", dir.display());
    }
    Ok(files)
}

/// The arrangements (our TOML) in `paths`, files or directories of them, each with its file
/// and its name (the file's `name`, else its stem).
pub fn named_arrangements(paths: &[PathBuf]) -> Result<Vec<(PathBuf, String, Arrangement)>> {
    arrangement_files(paths)?
        .into_iter()
        .map(|path| {
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            let arrangement = Arrangement::parse_toml(&text, &path)?;
            let name = arrangement.name.clone().unwrap_or_else(|| {
                path.file_stem().map_or_else(
                    || path.display().to_string(),
                    |s| s.to_string_lossy().into(),
                )
            });
            Ok((path, name, arrangement))
        })
        .collect()
}

/// The `.toml` files named, and those in the directories named, in order.
fn arrangement_files(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for path in paths {
        if path.is_dir() {
            files.extend(files_with_extension(path, "toml")?);
        } else {
            files.push(path.clone());
        }
    }
    Ok(files)
}
