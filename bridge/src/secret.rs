//! A run's secret: what a joining host presents to the central one. The file holds one line,
//! `<run id>:<password>`, the format of Zenoh's user/password dictionary, so the central
//! host's Zenoh checks joiners against the very file the run wrote.

use std::io::Write;
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use rand::RngExt;

/// Random bytes in a password (written as hex).
const PASSWORD_BYTES: usize = 32;

/// A run's credentials: Zenoh's user is the run id, its password the run's secret.
#[derive(Clone, PartialEq, Eq)]
pub struct RunSecret {
    pub run_id: String,
    password: String,
    /// The file it was read from or written to.
    pub file: PathBuf,
}

impl std::fmt::Debug for RunSecret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunSecret")
            .field("run_id", &self.run_id)
            .field("file", &self.file)
            .finish_non_exhaustive()
    }
}

impl RunSecret {
    /// Makes a new secret for `run_id` and writes it to `file`, readable by its owner alone.
    /// An existing file (a resumed run) is kept, so hosts that joined before join again.
    pub fn create_or_keep(file: &Path, run_id: &str) -> Result<Self> {
        if file.exists() {
            let kept = Self::read(file)?;
            if kept.run_id != run_id {
                bail!(
                    "{}: the secret of run {:?}, not {run_id:?}",
                    file.display(),
                    kept.run_id
                );
            }
            return Ok(kept);
        }
        let mut bytes = [0u8; PASSWORD_BYTES];
        rand::rng().fill(&mut bytes);
        let password: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        let mut out = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(file)
            .with_context(|| format!("creating {}", file.display()))?;
        writeln!(out, "{run_id}:{password}")
            .with_context(|| format!("writing {}", file.display()))?;
        Ok(Self {
            run_id: run_id.into(),
            password,
            file: file.into(),
        })
    }

    /// Reads a secret file; one that others may read is refused (a secret shared with every
    /// user of the machine protects nothing).
    pub fn read(file: &Path) -> Result<Self> {
        let mode = std::fs::metadata(file)
            .with_context(|| format!("reading the secret file {}", file.display()))?
            .permissions()
            .mode();
        if mode & 0o077 != 0 {
            bail!(
                "{}: the secret file is readable by others (mode {:o}): chmod 600 it",
                file.display(),
                mode & 0o777
            );
        }
        let text = std::fs::read_to_string(file)
            .with_context(|| format!("reading the secret file {}", file.display()))?;
        let line = text.lines().next().unwrap_or_default();
        let Some((run_id, password)) = line.split_once(':') else {
            bail!(
                "{}: line 1 is not `<run id>:<secret>` (a run's run.secret)",
                file.display()
            );
        };
        if run_id.is_empty() || password.len() < 2 * PASSWORD_BYTES {
            bail!(
                "{}: line 1 is not `<run id>:<secret>` with a {}-character secret",
                file.display(),
                2 * PASSWORD_BYTES
            );
        }
        Ok(Self {
            run_id: run_id.into(),
            password: password.into(),
            file: file.into(),
        })
    }

    pub(crate) fn password(&self) -> &str {
        &self.password
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_secret_is_written_for_its_owner_alone_and_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("run.secret");
        let made = RunSecret::create_or_keep(&file, "run-1").unwrap();
        let mode = std::fs::metadata(&file).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        assert_eq!(RunSecret::read(&file).unwrap(), made);
        assert_eq!(RunSecret::create_or_keep(&file, "run-1").unwrap(), made);
        let other = RunSecret::create_or_keep(&file, "run-2").unwrap_err();
        assert!(other.to_string().contains("not \"run-2\""), "{other}");
        assert!(!format!("{made:?}").contains(made.password()));
    }

    #[test]
    fn bad_secret_files_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("run.secret");
        for (text, mode, says) in [
            ("run-1\n", 0o600, "line 1"),
            ("run-1:short\n", 0o600, "64-character"),
            (
                &format!("run-1:{}\n", "a".repeat(64)),
                0o644,
                "readable by others",
            ),
        ] {
            std::fs::write(&file, text).unwrap();
            std::fs::set_permissions(&file, std::fs::Permissions::from_mode(mode)).unwrap();
            let err = RunSecret::read(&file).unwrap_err().to_string();
            assert!(err.contains("run.secret") && err.contains(says), "{err}");
        }
    }
}
