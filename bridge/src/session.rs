//! Opening the Zenoh sessions of a run: the central host's, which listens and checks every
//! joiner against the run's secret, and a joined host's, which connects with it. Both share
//! the settings that carry large steps without losing any.

use std::str::FromStr;

use anyhow::{Context, Result, bail};
use zenoh::{Config, Session, Wait};

use crate::secret::RunSecret;

/// Where the central host listens: `tcp/<address or host name>:<port>` (Zenoh's endpoint
/// syntax, TCP alone).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Endpoint(String);

impl FromStr for Endpoint {
    type Err = anyhow::Error;

    fn from_str(text: &str) -> Result<Self> {
        let address = text.strip_prefix("tcp/").with_context(|| {
            format!("endpoint {text:?}: expected tcp/<address>:<port>, e.g. tcp/10.0.0.1:7447")
        })?;
        match address.rsplit_once(':') {
            Some((host, port)) if !host.is_empty() && port.parse::<u16>().is_ok() => {
                Ok(Self(text.into()))
            }
            _ => bail!("endpoint {text:?}: expected tcp/<address>:<port>, e.g. tcp/10.0.0.1:7447"),
        }
    }
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// How long a blocked publication may wait for room before Zenoh closes the link. A step
/// waits as long as the buffer holds it back (the learner paces the run), so this is the
/// lease's business, not the queue's: an hour.
const BLOCK_BEFORE_CLOSE_US: u64 = 3_600_000_000;

/// Batches queued per link for data (Zenoh's most: 16 of 64 KiB): a step at 112 x 112 is two.
const DATA_QUEUE_BATCHES: usize = 16;

/// Bytes a link reads at once; Zenoh's default (one batch) reads a large step in pieces.
const RX_BUFFER_BYTES: usize = 16 << 20;

/// The largest message a link reassembles: a step at 448 x 448 with room to spare.
const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// How long the central host waits for a silent joined host before it ends the session
/// (the lease a host announces, in ms).
pub const HOST_LEASE_MS: u64 = 5_000;

/// How long a joined host waits for a silent central host (the lease the central host
/// announces, in ms): longer than [`HOST_LEASE_MS`], so that after a cut link the central
/// host has ended the session before the joined host reconnects. Zenoh 1.10 would otherwise
/// add the reconnecting host's link to the central host's stale session, and never send it
/// the central host's declarations again (eclipse-zenoh/zenoh#2806): the host would wait
/// for a central host it can no longer see.
pub const CENTRAL_LEASE_MS: u64 = 2 * HOST_LEASE_MS;

/// The settings both sides share; `lease_ms` is the lease this side announces.
fn base(mode: &str, lease_ms: u64) -> Result<Config> {
    let mut config = Config::default();
    let settings: [(&str, String); 10] = [
        ("mode", format!("{mode:?}")),
        // Hosts meet only at the endpoint given: no discovery on the network.
        ("scouting/multicast/enabled", "false".into()),
        ("scouting/gossip/enabled", "false".into()),
        (
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            BLOCK_BEFORE_CLOSE_US.to_string(),
        ),
        (
            "transport/link/tx/queue/size/data",
            DATA_QUEUE_BATCHES.to_string(),
        ),
        ("transport/link/rx/buffer_size", RX_BUFFER_BYTES.to_string()),
        (
            "transport/link/rx/max_message_size",
            MAX_MESSAGE_BYTES.to_string(),
        ),
        ("transport/link/tx/lease", lease_ms.to_string()),
        // Shared memory between the hosts' Zenoh sessions could not cross a machine, and the
        // hosts' own steps travel over iceoryx2.
        ("transport/shared_memory/enabled", "false".into()),
        ("adminspace/enabled", "false".into()),
    ];
    for (key, value) in settings {
        set(&mut config, key, &value)?;
    }
    Ok(config)
}

fn set(config: &mut Config, key: &str, value: &str) -> Result<()> {
    config
        .insert_json5(key, value)
        .map_err(|e| anyhow::anyhow!("Zenoh setting {key} = {value}: {e}"))
}

/// The central host's session: listens at `endpoint` and admits only hosts that present
/// `secret` (Zenoh checks them against the secret file itself).
pub fn listen(endpoint: &Endpoint, secret: &RunSecret) -> Result<Session> {
    let mut config = base("router", CENTRAL_LEASE_MS)?;
    set(
        &mut config,
        "listen/endpoints",
        &format!("[{:?}]", endpoint.0),
    )?;
    set(
        &mut config,
        "transport/auth/usrpwd/dictionary_file",
        &format!("{:?}", secret.file.display().to_string()),
    )?;
    zenoh::open(config)
        .wait()
        .map_err(|e| anyhow::anyhow!("listening at {endpoint}: {e}"))
}

/// A joined host's session: connects to the central host at `endpoint` as run `run_id` with
/// `secret`, and reconnects by itself when the link drops.
pub fn connect(endpoint: &Endpoint, run_id: &str, secret: &RunSecret) -> Result<Session> {
    let mut config = base("client", HOST_LEASE_MS)?;
    set(
        &mut config,
        "connect/endpoints",
        &format!("[{:?}]", endpoint.0),
    )?;
    set(
        &mut config,
        "transport/auth/usrpwd/user",
        &format!("{run_id:?}"),
    )?;
    set(
        &mut config,
        "transport/auth/usrpwd/password",
        &format!("{:?}", secret.password()),
    )?;
    zenoh::open(config).wait().map_err(|e| {
        anyhow::anyhow!(
            "cannot join run {run_id:?} at {endpoint}: {e} (nothing listens there, or it \
             refused us: the run id and the secret in {} must be the run's)",
            secret.file.display()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_are_checked() {
        for good in ["tcp/127.0.0.1:7447", "tcp/node-1:1", "tcp/[::1]:7447"] {
            Endpoint::from_str(good).unwrap();
        }
        for bad in [
            "127.0.0.1:7447",
            "udp/1.2.3.4:5",
            "tcp/host",
            "tcp/:7447",
            "tcp/h:99999",
        ] {
            let err = Endpoint::from_str(bad).unwrap_err().to_string();
            assert!(err.contains("tcp/<address>:<port>"), "{err}");
        }
    }
}
