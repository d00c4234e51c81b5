//! The encoding: "PG", the protocol version (u16, little-endian), then the message in
//! postcard. The version is read before anything else, so a process of another build is
//! refused with a clear error rather than misread.

use experience::Transition;
use sim::{Action, Heightmaps, ObjectId, PixelGrid, Primitive};

use crate::error::WireError;
use crate::message::{Message, Origin, Step};

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

/// The bytes of the largest step an actor sends on `grid`: a step carries one observation
/// whole, whatever the scene, so any step of the grid encodes to about this.
pub fn largest_step(grid: PixelGrid) -> usize {
    let step = Step {
        origin: Origin {
            actor: u32::MAX,
            incarnation: u32::MAX,
            seq: u64::MAX,
        },
        transition: Transition {
            episode: u64::MAX,
            step: u32::MAX,
            goal: ObjectId::MAX,
            obs: Heightmaps::new(grid),
            action: Action {
                primitive: Primitive::Push,
                rotation: u8::MAX,
                row: grid.side(),
                col: grid.side(),
            },
            reward: 0.0,
            grasped: Some(ObjectId::MAX),
            next_value: Some(0.0),
            next: None,
        },
        priority: 0.0,
        predicted_q: 0.0,
        explored: true,
        weights_version: u64::MAX,
    };
    let mut bytes = Vec::new();
    encode_into(&Message::Step(step), &mut bytes);
    bytes.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::message::{Control, Role};
    use sim::{Camera, SimConfig, Tabletop};

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

    #[test]
    fn a_step_of_a_real_scene_is_no_larger_than_the_largest() {
        let config = SimConfig::default();
        let grid = config.grid().unwrap();
        let (tabletop, _) = Tabletop::random(&config, 10, 3).unwrap();
        let mut step = Step {
            origin: Origin {
                actor: 3,
                incarnation: 1,
                seq: 812,
            },
            transition: Transition {
                episode: 40,
                step: 2,
                goal: 4,
                obs: Camera::new(grid).render(&tabletop),
                action: Action {
                    primitive: Primitive::Grasp,
                    rotation: 7,
                    row: 55,
                    col: 61,
                },
                reward: 1.0,
                grasped: Some(4),
                next_value: None,
                next: None,
            },
            priority: 0.7,
            predicted_q: 0.4,
            explored: false,
            weights_version: 118,
        };
        let mut bytes = Vec::new();
        encode_into(&Message::Step(step.clone()), &mut bytes);
        let largest = largest_step(grid);
        assert!(
            bytes.len() <= largest && bytes.len() + 64 > largest,
            "{} {largest}",
            bytes.len()
        );
        step.transition.obs = Heightmaps::new(PixelGrid::new(grid.pixel_size() / 2.0).unwrap());
        encode_into(&Message::Step(step), &mut bytes);
        assert!(bytes.len() > 3 * largest, "a finer grid's steps are larger");
    }
}
