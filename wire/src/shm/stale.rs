//! What killed processes leave of their iceoryx2 nodes and services that iceoryx2 0.10's own
//! cleanup never removes. A node is made in three steps: its directory with its details,
//! then its monitor token (by which `Node::list`, and so every cleanup, finds it), then its
//! service and port tags. A service's static config is made locked, then written. A process
//! killed inside a step leaves what the cleanup cannot see.

use std::collections::HashSet;
use std::path::Path;
use std::time::Duration;

use iceoryx2::prelude::Config;
use serde::Deserialize;

use super::PREFIX;

/// Marks the files a dead node's process left half-made in its node directory (`node`,
/// the node id) as finished, so iceoryx2's cleanup handles them. iceoryx2 writes a node's
/// details and its service and port tags read-write and makes each read-only once written;
/// its listing, and so its cleanup, passes over the read-write ones as being made, and the
/// directory they keep is never removed. The node's process is dead, so none will be
/// finished otherwise. A tag says by its name alone which service or port the node joined:
/// finished, the cleanup takes the node out of that service if it got in, else removes the
/// tag. Best effort: what this cannot change, the cleanup after reports.
pub(super) fn finish_half_made(config: &Config, node: &str) {
    use std::os::unix::fs::PermissionsExt;
    let dir = Path::new(config.global.node_dir().as_str()).join(node);
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        if entry.metadata().is_ok_and(|m| being_written(&m)) {
            let _ = std::fs::set_permissions(entry.path(), PermissionsExt::from_mode(0o400));
        }
    }
}

/// How long a half-made file whose owner cannot be read (a node directory without readable
/// details, a locked service) may stay unchanged before it is taken for abandoned: iceoryx2
/// finishes each microseconds after it begins it.
const ABANDONED_AFTER: Duration = Duration::from_secs(60);

/// What a node's details file says that this cleanup needs (it holds the node's config too).
#[derive(Deserialize)]
struct NodeDetails {
    process: u32,
    name: String,
}

/// Removes the node directories of pushgrasp processes killed before their node had a
/// monitor token (`listed`: the ids of the nodes `Node::list` found), with the token's
/// half-made files. Such a node joined no service, so its directory and token are all it
/// left; but unlisted, no cleanup ever removes them. A node is taken only when its details
/// name a pushgrasp process that is gone: a live one may be making its token now, and a
/// node whose details cannot be read may be anyone's, unless nothing in its directory has
/// changed for [`ABANDONED_AFTER`] (killed before its details were written: see
/// [`remove_if_abandoned`]). Returns how many were removed.
pub(super) fn remove_unmonitored(config: &Config, listed: &HashSet<String>) -> usize {
    let node_dir = config.global.node_dir();
    let node_dir = Path::new(node_dir.as_str());
    let Ok(entries) = std::fs::read_dir(node_dir) else {
        return 0;
    };
    let prefix = config.global.prefix.to_string();
    let details_file = format!("{prefix}node{}", config.global.node.static_config_suffix);
    let mut removed = 0;
    for entry in entries.flatten() {
        let id = entry.file_name().to_string_lossy().into_owned();
        let is_node = id.parse::<u128>().is_ok() && entry.path().is_dir();
        if !is_node || listed.contains(&id) {
            continue;
        }
        let details = std::fs::read_to_string(entry.path().join(&details_file))
            .ok()
            .and_then(|text| toml::from_str::<NodeDetails>(&text).ok());
        let Some(details) = details else {
            removed += usize::from(remove_if_abandoned(&entry.path(), &details_file));
            continue;
        };
        let ours = details.name.starts_with(&format!("{PREFIX}/"));
        let gone = !Path::new(&format!("/proc/{}", details.process)).exists();
        if !(ours && gone) || std::fs::remove_dir_all(entry.path()).is_err() {
            continue;
        }
        removed += 1;
        // The token's files, made or half-made: `<prefix><id><monitor suffix>[_context]`.
        let token = format!("{prefix}{id}.");
        for file in std::fs::read_dir(node_dir).into_iter().flatten().flatten() {
            if file.file_name().to_string_lossy().starts_with(&token) {
                let _ = std::fs::remove_file(file.path());
            }
        }
    }
    removed
}

/// Removes the static configs of services whose creator was killed before it wrote them:
/// iceoryx2 makes a service's static config read-write and empty (locked), writes it and
/// makes it read-only at once. A locked one tells every process that would open or create
/// the service that it is being made, so the service's name stays unusable (a run resumed
/// under its id cannot open its topics) and no cleanup removes it. Its owner cannot be read,
/// so it is taken only once unchanged for [`ABANDONED_AFTER`]. Returns how many were removed.
pub(super) fn remove_locked_services(config: &Config) -> usize {
    let (prefix, suffix) = (
        config.global.prefix.to_string(),
        config
            .global
            .service
            .static_config_storage_suffix
            .to_string(),
    );
    let service_dir = config.global.service_dir();
    let Ok(entries) = std::fs::read_dir(service_dir.as_str()) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let locked = entry
            .metadata()
            .is_ok_and(|m| being_written(&m) && unchanged(&m));
        if name.starts_with(&prefix)
            && name.ends_with(&suffix)
            && locked
            && std::fs::remove_file(entry.path()).is_ok()
        {
            removed += 1;
        }
    }
    removed
}

/// Whether a file is one iceoryx2 has begun and not finished: it makes its files read-write
/// (0600) and read-only once written.
fn being_written(metadata: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::PermissionsExt;
    metadata.is_file() && metadata.permissions().mode() & 0o777 == 0o600
}

/// Whether a file or directory has not changed for [`ABANDONED_AFTER`].
fn unchanged(metadata: &std::fs::Metadata) -> bool {
    metadata
        .modified()
        .is_ok_and(|changed| changed.elapsed().is_ok_and(|age| age > ABANDONED_AFTER))
}

/// A node directory that holds nothing but, at most, its details file half-written (not
/// readable as details), neither changed for [`ABANDONED_AFTER`]: its process was killed
/// before it had written them.
fn remove_if_abandoned(dir: &Path, details_file: &str) -> bool {
    let left = |path: &Path| path.metadata().is_ok_and(|m| unchanged(&m));
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    let nothing_else =
        (entries.flatten()).all(|file| file.file_name() == details_file && left(&file.path()));
    nothing_else && left(dir) && std::fs::remove_dir_all(dir).is_ok()
}
