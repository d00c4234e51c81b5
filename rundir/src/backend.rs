//! Which backend runs each role's nets (`[backend]` in a run config, `--backend` on the
//! command line), opened where the nets live, with the adapter written into the role's log.

use std::collections::BTreeMap;

use anyhow::{Context, Result};
use mcaplog::RunLog;
pub use qnet::Backend;
use qnet::Device;
use serde::{Deserialize, Serialize};

/// The learner's and the actors' backends: `cpu` (burn-flex) or `wgpu` (a GPU through
/// burn-wgpu, in a build with `--features wgpu`). A GPU learner with CPU actors is the
/// common layout.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Backends {
    pub learner: Backend,
    pub actors: Backend,
}

impl Backends {
    /// Opens each backend the run names, before any role starts, so that a build or a
    /// machine without one is refused at once; prints the adapter of each GPU backend.
    pub fn check(&self) -> Result<()> {
        for (field, whose, backend) in [
            ("learner", "the learner's", self.learner),
            ("actors", "the actors'", self.actors),
        ] {
            if let Some(adapter) = open(backend, field)?.adapter {
                println!("{whose} nets on {backend}: {adapter}");
            }
        }
        Ok(())
    }
}

/// `--backend B` as the setting it stands for: both roles on `B`.
pub fn setting(backend: Backend) -> toml::Table {
    let both = toml::Table::from_iter(
        ["learner", "actors"].map(|role| (role.to_string(), backend.name().into())),
    );
    toml::Table::from_iter([("backend".to_string(), both.into())])
}

/// `backend`'s device for a role's nets (`field`: the role's key under `[backend]`); the
/// adapter (or the CPU) goes into `log` as its `device` metadata.
pub fn open_device(backend: Backend, field: &str, log: &RunLog) -> Result<Device> {
    let open = open(backend, field)?;
    let mut values = BTreeMap::from([("backend".to_string(), backend.name().to_string())]);
    if let Some(adapter) = open.adapter {
        values.extend([
            ("adapter".to_string(), adapter.name),
            ("driver".to_string(), adapter.driver),
            ("api".to_string(), adapter.api),
            ("kind".to_string(), adapter.kind),
        ]);
    }
    log.metadata("device", &values)?;
    Ok(open.device)
}

/// `backend`'s device, opened; errors name the role's key under `[backend]` and the flag.
pub fn open(backend: Backend, field: &str) -> Result<qnet::OpenDevice> {
    backend
        .open()
        .with_context(|| format!("backend.{field} = \"{backend}\" (--backend)"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flag_sets_both_roles() {
        let text = toml::to_string(&setting(Backend::Wgpu)).unwrap();
        #[derive(Deserialize)]
        struct Holder {
            backend: Backends,
        }
        let read: Holder = toml::from_str(&text).unwrap();
        assert_eq!(
            read.backend,
            Backends {
                learner: Backend::Wgpu,
                actors: Backend::Wgpu
            }
        );
    }
}
