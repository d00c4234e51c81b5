//! Joining a run: a host asks the central one (a Zenoh query on the run's join key) for a
//! place, and gets its actors' indices and the run's config, or the reason it is refused.
//! Both ways the bytes start with the wire's protocol version, read before anything else, so
//! a host of another build is refused by number rather than misread.

use serde::{Deserialize, Serialize};
use thiserror::Error;
use wire::PROTOCOL_VERSION;

/// What a host asks.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct JoinRequest {
    pub run_id: String,
    /// The host's name in the run (its machine's name unless given): the same host joining
    /// again gets the same actor indices.
    pub host: String,
    /// Actors it runs.
    pub actors: u32,
}

/// Where a host's actors stand in the run.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Placement {
    /// Its actors are indices `first_actor..first_actor + actors` of the run.
    pub first_actor: u32,
    /// Its actors' first incarnation: above every incarnation its earlier joins used, so the
    /// buffer tells their streams apart.
    pub incarnation: u32,
    /// The run's config (TOML), as the central host resolved it.
    pub config: String,
}

/// The central host's answer.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum JoinReply {
    Accepted(Placement),
    Refused(String),
}

#[derive(Debug, Error, PartialEq, Eq)]
pub enum JoinError {
    #[error(
        "protocol version {found}, this build speaks {expected}: run the same pushgrasp build on every host"
    )]
    Version { found: u16, expected: u16 },
    #[error("not a join message: {0}")]
    Malformed(String),
}

/// Encodes a request or reply after the protocol version.
pub fn encode<T: Serialize>(message: &T) -> Vec<u8> {
    postcard::to_extend(message, PROTOCOL_VERSION.to_le_bytes().to_vec())
        .expect("join messages serialise into a Vec")
}

/// Decodes what [`encode`] wrote, refusing another protocol version.
pub fn decode<T: for<'de> Deserialize<'de>>(bytes: &[u8]) -> Result<T, JoinError> {
    let (version, body) = bytes
        .split_first_chunk::<2>()
        .ok_or_else(|| JoinError::Malformed(format!("{} bytes", bytes.len())))?;
    let found = u16::from_le_bytes(*version);
    if found != PROTOCOL_VERSION {
        return Err(JoinError::Version {
            found,
            expected: PROTOCOL_VERSION,
        });
    }
    postcard::from_bytes(body).map_err(|e| JoinError::Malformed(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_round_trip_and_other_versions_are_refused() {
        let request = JoinRequest {
            run_id: "r".into(),
            host: "node-2".into(),
            actors: 4,
        };
        let bytes = encode(&request);
        assert_eq!(decode::<JoinRequest>(&bytes), Ok(request));
        let mut other = bytes.clone();
        other[..2].copy_from_slice(&(PROTOCOL_VERSION + 1).to_le_bytes());
        let err = decode::<JoinRequest>(&other).unwrap_err();
        assert!(err.to_string().contains("same pushgrasp build"), "{err}");
        assert!(matches!(
            decode::<JoinRequest>(&bytes[..3]),
            Err(JoinError::Malformed(_))
        ));
    }
}
