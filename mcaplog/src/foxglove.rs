//! The Foxglove message schemas this crate writes, in protobuf encoding.
//!
//! The structs carry the fields of `foxglove.RawImage`, `foxglove.CompressedImage`,
//! `foxglove.Log` and `foxglove.SceneUpdate` (same names, numbers and types as Foxglove's
//! published `.proto` files; fields this project never sets, such as the newer optional
//! `message_id` and `lineage`, are left out, which protobuf allows). The
//! MCAP schema of each is a `FileDescriptorSet` built here in code from the same field list, so
//! there is no `protoc` step and no generated file to keep in step: the descriptor and the
//! struct are side by side below.
//!
//! Its length is the schemas themselves: each message's struct beside its descriptor, which are
//! kept in step by being read together.

use prost::Message;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{
    DescriptorProto, EnumDescriptorProto, EnumValueDescriptorProto, FieldDescriptorProto,
    FileDescriptorProto, FileDescriptorSet,
};

/// `foxglove.RawImage`: an uncompressed image.
#[derive(Clone, PartialEq, Message)]
pub struct RawImage {
    /// Timestamp of the image.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<prost_types::Timestamp>,
    /// Frame of reference of the image.
    #[prost(string, tag = "7")]
    pub frame_id: String,
    /// Width in pixels.
    #[prost(fixed32, tag = "2")]
    pub width: u32,
    /// Height in pixels.
    #[prost(fixed32, tag = "3")]
    pub height: u32,
    /// Pixel encoding: `rgb8`, `rgba8`, `bgr8`, `bgra8`, `mono8`, `mono16`, `32FC1`, ...
    #[prost(string, tag = "4")]
    pub encoding: String,
    /// Bytes in one row.
    #[prost(fixed32, tag = "5")]
    pub step: u32,
    /// The pixels, row after row.
    #[prost(bytes = "vec", tag = "6")]
    pub data: Vec<u8>,
}

/// `foxglove.CompressedImage`: an image in a file format (`png`, `jpeg`, `webp`, `avif`).
#[derive(Clone, PartialEq, Message)]
pub struct CompressedImage {
    /// Timestamp of the image.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<prost_types::Timestamp>,
    /// Frame of reference of the image.
    #[prost(string, tag = "4")]
    pub frame_id: String,
    /// The encoded image.
    #[prost(bytes = "vec", tag = "2")]
    pub data: Vec<u8>,
    /// Its format: `png`, `jpeg`, `webp` or `avif`.
    #[prost(string, tag = "3")]
    pub format: String,
}

/// `foxglove.Log`: one log line.
#[derive(Clone, PartialEq, Message)]
pub struct Log {
    /// When it was logged.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<prost_types::Timestamp>,
    /// Its level, a [`LogLevel`].
    #[prost(enumeration = "LogLevel", tag = "2")]
    pub level: i32,
    /// The text.
    #[prost(string, tag = "3")]
    pub message: String,
    /// Process or node name.
    #[prost(string, tag = "4")]
    pub name: String,
    /// Source file.
    #[prost(string, tag = "5")]
    pub file: String,
    /// Line in that file.
    #[prost(fixed32, tag = "6")]
    pub line: u32,
}

/// `foxglove.Log.Level`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, prost::Enumeration)]
#[repr(i32)]
pub enum LogLevel {
    /// Unknown level.
    Unknown = 0,
    /// Debugging detail.
    Debug = 1,
    /// Normal operation.
    Info = 2,
    /// Something unexpected that the process survives.
    Warning = 3,
    /// An error.
    Error = 4,
    /// An error the process does not survive.
    Fatal = 5,
}

/// `foxglove.SceneUpdate`: entities to add to (or replace in) a 3D scene.
#[derive(Clone, PartialEq, Message)]
pub struct SceneUpdate {
    /// The entities; one replaces an earlier one on the same topic with the same id.
    #[prost(message, repeated, tag = "2")]
    pub entities: Vec<SceneEntity>,
}

/// `foxglove.SceneEntity`: one thing in the scene, here made of boxes.
#[derive(Clone, PartialEq, Message)]
pub struct SceneEntity {
    /// When the entity was seen.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<prost_types::Timestamp>,
    /// Frame of reference of the primitives.
    #[prost(string, tag = "2")]
    pub frame_id: String,
    /// Identifier: an entity replaces the one with the same id.
    #[prost(string, tag = "3")]
    pub id: String,
    /// Removed this long after `timestamp`; zero (or none) keeps it until replaced.
    #[prost(message, optional, tag = "4")]
    pub lifetime: Option<prost_types::Duration>,
    /// Whether it follows `frame_id` as that frame moves.
    #[prost(bool, tag = "5")]
    pub frame_locked: bool,
    /// Boxes.
    #[prost(message, repeated, tag = "8")]
    pub cubes: Vec<CubePrimitive>,
}

/// `foxglove.CubePrimitive`: a box.
#[derive(Clone, PartialEq, Message)]
pub struct CubePrimitive {
    /// Its centre and orientation.
    #[prost(message, optional, tag = "1")]
    pub pose: Option<Pose>,
    /// Its full extent along each of its axes (metres).
    #[prost(message, optional, tag = "2")]
    pub size: Option<Vector3>,
    #[prost(message, optional, tag = "3")]
    pub color: Option<Color>,
}

/// `foxglove.Pose`.
#[derive(Clone, PartialEq, Message)]
pub struct Pose {
    #[prost(message, optional, tag = "1")]
    pub position: Option<Vector3>,
    #[prost(message, optional, tag = "2")]
    pub orientation: Option<Quaternion>,
}

/// `foxglove.Vector3`.
#[derive(Clone, Copy, PartialEq, Message)]
pub struct Vector3 {
    #[prost(double, tag = "1")]
    pub x: f64,
    #[prost(double, tag = "2")]
    pub y: f64,
    #[prost(double, tag = "3")]
    pub z: f64,
}

/// `foxglove.Quaternion`.
#[derive(Clone, Copy, PartialEq, Message)]
pub struct Quaternion {
    #[prost(double, tag = "1")]
    pub x: f64,
    #[prost(double, tag = "2")]
    pub y: f64,
    #[prost(double, tag = "3")]
    pub z: f64,
    #[prost(double, tag = "4")]
    pub w: f64,
}

/// `foxglove.Color`: RGBA, each from 0 to 1.
#[derive(Clone, Copy, PartialEq, Message)]
pub struct Color {
    #[prost(double, tag = "1")]
    pub r: f64,
    #[prost(double, tag = "2")]
    pub g: f64,
    #[prost(double, tag = "3")]
    pub b: f64,
    #[prost(double, tag = "4")]
    pub a: f64,
}

/// A protobuf timestamp from nanoseconds since the Unix epoch.
pub fn timestamp(ns: u64) -> prost_types::Timestamp {
    prost_types::Timestamp {
        seconds: (ns / 1_000_000_000) as i64,
        nanos: (ns % 1_000_000_000) as i32,
    }
}

/// The schema name (the message's full protobuf name) and the serialized `FileDescriptorSet`.
pub(crate) struct ProtoSchema {
    pub name: &'static str,
    pub descriptor_set: Vec<u8>,
}

const TIMESTAMP_FILE: &str = "google/protobuf/timestamp.proto";
const TIMESTAMP_TYPE: &str = ".google.protobuf.Timestamp";
const DURATION_FILE: &str = "google/protobuf/duration.proto";
const DURATION_TYPE: &str = ".google.protobuf.Duration";

fn field(name: &str, number: i32, ty: Type, type_name: Option<&str>) -> FieldDescriptorProto {
    FieldDescriptorProto {
        name: Some(name.into()),
        number: Some(number),
        label: Some(Label::Optional as i32),
        r#type: Some(ty as i32),
        type_name: type_name.map(Into::into),
        json_name: Some(json_name(name)),
        ..Default::default()
    }
}

/// protoc's default JSON name: lowerCamelCase of the field name.
fn json_name(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    let mut upper = false;
    for c in name.chars() {
        if c == '_' {
            upper = true;
        } else if upper {
            out.extend(c.to_uppercase());
            upper = false;
        } else {
            out.push(c);
        }
    }
    out
}

/// A repeated field of messages.
fn repeated(name: &str, number: i32, type_name: &str) -> FieldDescriptorProto {
    FieldDescriptorProto {
        label: Some(Label::Repeated as i32),
        ..field(name, number, Type::Message, Some(type_name))
    }
}

/// A message of `fields`.
fn message(name: &str, fields: Vec<FieldDescriptorProto>) -> DescriptorProto {
    DescriptorProto {
        name: Some(name.into()),
        field: fields,
        ..Default::default()
    }
}

/// `google/protobuf/timestamp.proto` or `duration.proto` as protoc describes them (the
/// message, without options): both are seconds and nanoseconds.
fn seconds_nanos_file(file: &str, name: &str) -> FileDescriptorProto {
    FileDescriptorProto {
        name: Some(file.into()),
        package: Some("google.protobuf".into()),
        message_type: vec![DescriptorProto {
            name: Some(name.into()),
            field: vec![
                field("seconds", 1, Type::Int64, None),
                field("nanos", 2, Type::Int32, None),
            ],
            ..Default::default()
        }],
        syntax: Some("proto3".into()),
        ..Default::default()
    }
}

/// The schema `foxglove.<name>`: a file `foxglove/<name>.proto` whose first message is the
/// schema's; the others are the types it uses.
fn foxglove_schema(name: &'static str, messages: Vec<DescriptorProto>) -> ProtoSchema {
    let file = format!("{}.proto", name.replace('.', "/"));
    let set = FileDescriptorSet {
        file: vec![
            seconds_nanos_file(TIMESTAMP_FILE, "Timestamp"),
            seconds_nanos_file(DURATION_FILE, "Duration"),
            FileDescriptorProto {
                name: Some(file),
                package: Some("foxglove".into()),
                dependency: vec![TIMESTAMP_FILE.into(), DURATION_FILE.into()],
                message_type: messages,
                syntax: Some("proto3".into()),
                ..Default::default()
            },
        ],
    };
    ProtoSchema {
        name,
        descriptor_set: set.encode_to_vec(),
    }
}

pub(crate) fn raw_image_schema() -> ProtoSchema {
    let message = message(
        "RawImage",
        vec![
            field("timestamp", 1, Type::Message, Some(TIMESTAMP_TYPE)),
            field("frame_id", 7, Type::String, None),
            field("width", 2, Type::Fixed32, None),
            field("height", 3, Type::Fixed32, None),
            field("encoding", 4, Type::String, None),
            field("step", 5, Type::Fixed32, None),
            field("data", 6, Type::Bytes, None),
        ],
    );
    foxglove_schema("foxglove.RawImage", vec![message])
}

pub(crate) fn compressed_image_schema() -> ProtoSchema {
    let message = message(
        "CompressedImage",
        vec![
            field("timestamp", 1, Type::Message, Some(TIMESTAMP_TYPE)),
            field("frame_id", 4, Type::String, None),
            field("data", 2, Type::Bytes, None),
            field("format", 3, Type::String, None),
        ],
    );
    foxglove_schema("foxglove.CompressedImage", vec![message])
}

pub(crate) fn log_schema() -> ProtoSchema {
    let level_values = [
        ("UNKNOWN", 0),
        ("DEBUG", 1),
        ("INFO", 2),
        ("WARNING", 3),
        ("ERROR", 4),
        ("FATAL", 5),
    ];
    let level = EnumDescriptorProto {
        name: Some("Level".into()),
        value: level_values
            .iter()
            .map(|&(name, number)| EnumValueDescriptorProto {
                name: Some(name.into()),
                number: Some(number),
                ..Default::default()
            })
            .collect(),
        ..Default::default()
    };
    let message = DescriptorProto {
        name: Some("Log".into()),
        field: vec![
            field("timestamp", 1, Type::Message, Some(TIMESTAMP_TYPE)),
            field("level", 2, Type::Enum, Some(".foxglove.Log.Level")),
            field("message", 3, Type::String, None),
            field("name", 4, Type::String, None),
            field("file", 5, Type::String, None),
            field("line", 6, Type::Fixed32, None),
        ],
        enum_type: vec![level],
        ..Default::default()
    };
    foxglove_schema("foxglove.Log", vec![message])
}

pub(crate) fn scene_update_schema() -> ProtoSchema {
    let doubles = |names: &[&str]| {
        names
            .iter()
            .zip(1..)
            .map(|(name, number)| field(name, number, Type::Double, None))
            .collect()
    };
    // Every field of SceneUpdate and SceneEntity is declared, so readers that walk each
    // primitive list find an empty one; the primitives this project never draws are declared
    // without fields, which decodes the same (none are written).
    let unused = [
        "SceneEntityDeletion",
        "KeyValuePair",
        "ArrowPrimitive",
        "SpherePrimitive",
        "CylinderPrimitive",
        "LinePrimitive",
        "TriangleListPrimitive",
        "TextPrimitive",
        "ModelPrimitive",
    ];
    let mut messages = vec![
        message(
            "SceneUpdate",
            vec![
                repeated("deletions", 1, ".foxglove.SceneEntityDeletion"),
                repeated("entities", 2, ".foxglove.SceneEntity"),
            ],
        ),
        message(
            "SceneEntity",
            vec![
                field("timestamp", 1, Type::Message, Some(TIMESTAMP_TYPE)),
                field("frame_id", 2, Type::String, None),
                field("id", 3, Type::String, None),
                field("lifetime", 4, Type::Message, Some(DURATION_TYPE)),
                field("frame_locked", 5, Type::Bool, None),
                repeated("metadata", 6, ".foxglove.KeyValuePair"),
                repeated("arrows", 7, ".foxglove.ArrowPrimitive"),
                repeated("cubes", 8, ".foxglove.CubePrimitive"),
                repeated("spheres", 9, ".foxglove.SpherePrimitive"),
                repeated("cylinders", 10, ".foxglove.CylinderPrimitive"),
                repeated("lines", 11, ".foxglove.LinePrimitive"),
                repeated("triangles", 12, ".foxglove.TriangleListPrimitive"),
                repeated("texts", 13, ".foxglove.TextPrimitive"),
                repeated("models", 14, ".foxglove.ModelPrimitive"),
            ],
        ),
        message(
            "CubePrimitive",
            vec![
                field("pose", 1, Type::Message, Some(".foxglove.Pose")),
                field("size", 2, Type::Message, Some(".foxglove.Vector3")),
                field("color", 3, Type::Message, Some(".foxglove.Color")),
            ],
        ),
        message(
            "Pose",
            vec![
                field("position", 1, Type::Message, Some(".foxglove.Vector3")),
                field(
                    "orientation",
                    2,
                    Type::Message,
                    Some(".foxglove.Quaternion"),
                ),
            ],
        ),
        message("Vector3", doubles(&["x", "y", "z"])),
        message("Quaternion", doubles(&["x", "y", "z", "w"])),
        message("Color", doubles(&["r", "g", "b", "a"])),
    ];
    messages.extend(unused.iter().map(|name| message(name, Vec::new())));
    foxglove_schema("foxglove.SceneUpdate", messages)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every field of each struct is declared in its descriptor with the same number and a
    /// compatible type: a message encoded by the struct decodes field by field against it.
    #[test]
    fn descriptors_match_the_structs() {
        fn fields(schema: &ProtoSchema) -> Vec<(String, i32, i32)> {
            let set = FileDescriptorSet::decode(schema.descriptor_set.as_slice()).unwrap();
            let file = set.file.last().unwrap();
            let message = &file.message_type[0];
            assert_eq!(
                format!("{}.{}", file.package(), message.name()),
                schema.name,
                "schema name is the full message name"
            );
            let mut out: Vec<_> = message
                .field
                .iter()
                .map(|f| (f.name().to_string(), f.number(), f.r#type))
                .map(|(n, k, t)| (n, k, t.unwrap()))
                .collect();
            out.sort_by_key(|f| f.1);
            out
        }
        let t = |ty: Type| ty as i32;
        assert_eq!(
            fields(&raw_image_schema()),
            vec![
                ("timestamp".into(), 1, t(Type::Message)),
                ("width".into(), 2, t(Type::Fixed32)),
                ("height".into(), 3, t(Type::Fixed32)),
                ("encoding".into(), 4, t(Type::String)),
                ("step".into(), 5, t(Type::Fixed32)),
                ("data".into(), 6, t(Type::Bytes)),
                ("frame_id".into(), 7, t(Type::String)),
            ]
        );
        assert_eq!(fields(&compressed_image_schema()).len(), 4);
        assert_eq!(fields(&log_schema()).len(), 6);
        let scene = fields(&scene_update_schema());
        assert_eq!(scene[1].0, "entities");
        assert_eq!(json_name("frame_id"), "frameId");
    }

    #[test]
    fn timestamps_split_seconds_and_nanoseconds() {
        let t = timestamp(1_700_000_000_123_456_789);
        assert_eq!((t.seconds, t.nanos), (1_700_000_000, 123_456_789));
    }
}
