//! Checkpoints: a directory holding both nets' weights (burn's burnpack format) and a small
//! manifest saying which stage and update they come from and which configuration made them.

use std::hash::Hasher;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::LearnerError;

const WEIGHTS: &str = "weights.bpk";
const MANIFEST: &str = "manifest.toml";

/// What a checkpoint says about itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// The training stage (1, 2 or 3).
    pub stage: u8,
    /// Learner updates taken when it was written.
    pub updates: u64,
    /// Heightmap side the nets were trained at.
    pub side: usize,
    /// FNV-1a hash of the network configuration (as TOML): weights only load into nets of
    /// the same shape.
    pub config_hash: String,
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

    /// Writes the weights, then the manifest (so a manifest always names complete weights).
    pub fn save(&self, manifest: &Manifest, weights: &[u8]) -> Result<(), LearnerError> {
        std::fs::create_dir_all(&self.dir).map_err(|e| self.error(&self.dir, e))?;
        let weights_path = self.dir.join(WEIGHTS);
        let tmp = self.dir.join(format!("{WEIGHTS}.tmp"));
        std::fs::write(&tmp, weights).map_err(|e| self.error(&tmp, e))?;
        std::fs::rename(&tmp, &weights_path).map_err(|e| self.error(&weights_path, e))?;
        let manifest_path = self.dir.join(MANIFEST);
        let text = toml::to_string(manifest).expect("manifests serialise");
        std::fs::write(&manifest_path, text).map_err(|e| self.error(&manifest_path, e))
    }

    /// Reads the manifest and the weights, checking the configuration hash.
    pub fn load(&self, expected_hash: &str) -> Result<(Manifest, Vec<u8>), LearnerError> {
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
        let weights_path = self.dir.join(WEIGHTS);
        let weights = std::fs::read(&weights_path).map_err(|e| self.error(&weights_path, e))?;
        Ok((manifest, weights))
    }
}
