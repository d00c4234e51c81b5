//! Checkpoints: a directory holding both nets' weights (burn's burnpack format) and a small
//! manifest saying which stage and update they come from and which configuration made them.
//! When the learner averages its nets, the weights are the average (what eval and the next
//! stage use) and the trained nets are kept beside them, for `--resume`.

use std::hash::Hasher;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::LearnerError;

const WEIGHTS: &str = "weights.bpk";
const TRAINED: &str = "trained.bpk";
const MANIFEST: &str = "manifest.toml";

/// What a checkpoint says about itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// The training stage (1, 2 or 3; 0 for trunks pretrained by `pushgrasp pretrain`).
    pub stage: u8,
    /// Learner updates taken when it was written.
    pub updates: u64,
    /// Heightmap side the nets were trained at.
    pub side: usize,
    /// FNV-1a hash of the network configuration (as TOML): weights only load into nets of
    /// the same shape.
    pub config_hash: String,
}

/// What a checkpoint holds.
#[derive(Clone, Debug, PartialEq)]
pub struct SavedNets {
    pub manifest: Manifest,
    /// The nets to use: the trained ones, or their average when the learner averages.
    pub weights: Vec<u8>,
    /// The trained nets, when `weights` is their average.
    pub trained: Option<Vec<u8>>,
}

/// A checkpoint directory.
pub struct Checkpoint {
    dir: PathBuf,
}

/// A stable hash of a configuration's TOML form.
pub fn config_hash<T: Serialize>(config: &T) -> String {
    let text = toml::to_string(config).expect("configurations serialise");
    let mut hasher = fnv::FnvHasher::default();
    hasher.write(text.as_bytes());
    format!("{:016x}", hasher.finish())
}

impl Checkpoint {
    pub fn at(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn error(&self, path: &Path, message: impl ToString) -> LearnerError {
        LearnerError::Checkpoint {
            path: path.to_path_buf(),
            message: message.to_string(),
        }
    }

    /// Writes the weights (and the trained nets, when they differ), then the manifest, so a
    /// manifest always names complete weights.
    pub fn save(&self, saved: &SavedNets) -> Result<(), LearnerError> {
        std::fs::create_dir_all(&self.dir).map_err(|e| self.error(&self.dir, e))?;
        self.write_atomically(WEIGHTS, &saved.weights)?;
        let trained_path = self.dir.join(TRAINED);
        match &saved.trained {
            Some(trained) => self.write_atomically(TRAINED, trained)?,
            None if trained_path.exists() => {
                std::fs::remove_file(&trained_path).map_err(|e| self.error(&trained_path, e))?
            }
            None => {}
        }
        let manifest_path = self.dir.join(MANIFEST);
        let text = toml::to_string(&saved.manifest).expect("manifests serialise");
        std::fs::write(&manifest_path, text).map_err(|e| self.error(&manifest_path, e))
    }

    fn write_atomically(&self, name: &str, bytes: &[u8]) -> Result<(), LearnerError> {
        let path = self.dir.join(name);
        let tmp = self.dir.join(format!("{name}.tmp"));
        std::fs::write(&tmp, bytes).map_err(|e| self.error(&tmp, e))?;
        std::fs::rename(&tmp, &path).map_err(|e| self.error(&path, e))
    }

    /// Reads the manifest, the weights and any trained nets, checking the configuration
    /// hash.
    pub fn load(&self, expected_hash: &str) -> Result<SavedNets, LearnerError> {
        let manifest_path = self.dir.join(MANIFEST);
        let text =
            std::fs::read_to_string(&manifest_path).map_err(|e| self.error(&manifest_path, e))?;
        let manifest: Manifest =
            toml::from_str(&text).map_err(|e| self.error(&manifest_path, e))?;
        if manifest.config_hash != expected_hash {
            return Err(self.error(
                &manifest_path,
                format!(
                    "config_hash {} does not match this network configuration ({expected_hash})",
                    manifest.config_hash
                ),
            ));
        }
        let read = |path: PathBuf| std::fs::read(&path).map_err(|e| self.error(&path, e));
        let weights = read(self.dir.join(WEIGHTS))?;
        let trained_path = self.dir.join(TRAINED);
        let trained = trained_path
            .exists()
            .then(|| read(trained_path))
            .transpose()?;
        Ok(SavedNets {
            manifest,
            weights,
            trained,
        })
    }
}
