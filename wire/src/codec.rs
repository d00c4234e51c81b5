//! The encoding: "PG", the protocol version (u16, little-endian), then the message in
//! postcard. The version is read before anything else, so a process of another build is
//! refused with a clear error rather than misread.

use crate::error::WireError;
use crate::message::Message;

/// The version of [`Message`]'s encoding; raise it with any change to the messages.
pub const PROTOCOL_VERSION: u16 = 8;

const MAGIC: [u8; 2] = *b"PG";
const HEADER: usize = 4;

/// Encodes `message` into `out` (cleared first, so a caller can reuse its allocation).
pub fn encode_into(message: &Message, out: &mut Vec<u8>) {
    encode_with_version(message, PROTOCOL_VERSION, out);
}

/// As [`encode_into`] with a chosen version: what another build would send.
pub fn encode_with_version(message: &Message, version: u16, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&version.to_le_bytes());
    let body = std::mem::take(out);
    *out = postcard::to_extend(message, body).expect("messages serialise into a Vec");
}

/// Decodes a message, refusing any other protocol version.
pub fn decode(bytes: &[u8]) -> Result<Message, WireError> {
    if bytes.len() < HEADER || bytes[..2] != MAGIC {
        return Err(WireError::NotAMessage { len: bytes.len() });
    }
    let version = u16::from_le_bytes([bytes[2], bytes[3]]);
    if version != PROTOCOL_VERSION {
        return Err(WireError::Version {
            found: version,
            expected: PROTOCOL_VERSION,
        });
    }
    postcard::from_bytes(&bytes[HEADER..]).map_err(|e| WireError::Malformed {
        version,
        why: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::message::{Control, Role};

    fn encoded(message: &Message, version: u16) -> Vec<u8> {
        let mut out = Vec::new();
        encode_with_version(message, version, &mut out);
        out
    }

    #[test]
    fn a_message_round_trips() {
        let message = Message::Control(Control::Stop(Role::Learner));
        assert_eq!(decode(&encoded(&message, PROTOCOL_VERSION)), Ok(message));
    }

    #[test]
    fn another_version_is_refused_by_number() {
        let message = Message::Control(Control::Snapshot);
        let err = decode(&encoded(&message, PROTOCOL_VERSION + 1)).unwrap_err();
        assert_eq!(
            err,
            WireError::Version {
                found: PROTOCOL_VERSION + 1,
                expected: PROTOCOL_VERSION
            }
        );
        assert!(err.to_string().contains("same pushgrasp build"));
    }

    #[test]
    fn foreign_and_truncated_bytes_are_refused() {
        assert_eq!(decode(b"PG"), Err(WireError::NotAMessage { len: 2 }));
        assert_eq!(decode(b"{\"a\":1}"), Err(WireError::NotAMessage { len: 7 }));
        let mut bytes = encoded(&Message::Control(Control::Snapshot), PROTOCOL_VERSION);
        bytes.truncate(4);
        assert!(matches!(decode(&bytes), Err(WireError::Malformed { .. })));
    }
}
