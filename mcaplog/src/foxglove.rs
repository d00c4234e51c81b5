//! The Foxglove message schemas this crate writes, in protobuf encoding.
//!
//! The structs carry the fields of `foxglove.RawImage`, `foxglove.CompressedImage` and
//! `foxglove.Log` (same names, numbers and types as Foxglove's published `.proto` files; the
//! newer optional fields `message_id` and `lineage` are left out, which protobuf allows). The
//! MCAP schema of each is a `FileDescriptorSet` built here in code from the same field list, so
//! there is no `protoc` step and no generated file to keep in step: the descriptor and the
//! struct are side by side below.

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

/// `google/protobuf/timestamp.proto` as protoc describes it (the message, without options).
fn timestamp_file() -> FileDescriptorProto {
    FileDescriptorProto {
        name: Some(TIMESTAMP_FILE.into()),
        package: Some("google.protobuf".into()),
        message_type: vec![DescriptorProto {
            name: Some("Timestamp".into()),
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

fn foxglove_file(file: &str, message: DescriptorProto) -> FileDescriptorSet {
    FileDescriptorSet {
        file: vec![
            timestamp_file(),
            FileDescriptorProto {
                name: Some(file.into()),
                package: Some("foxglove".into()),
                dependency: vec![TIMESTAMP_FILE.into()],
                message_type: vec![message],
                syntax: Some("proto3".into()),
                ..Default::default()
            },
        ],
    }
}

pub(crate) fn raw_image_schema() -> ProtoSchema {
    let message = DescriptorProto {
        name: Some("RawImage".into()),
        field: vec![
            field("timestamp", 1, Type::Message, Some(TIMESTAMP_TYPE)),
            field("frame_id", 7, Type::String, None),
            field("width", 2, Type::Fixed32, None),
            field("height", 3, Type::Fixed32, None),
            field("encoding", 4, Type::String, None),
            field("step", 5, Type::Fixed32, None),
            field("data", 6, Type::Bytes, None),
        ],
        ..Default::default()
    };
    ProtoSchema {
        name: "foxglove.RawImage",
        descriptor_set: foxglove_file("foxglove/RawImage.proto", message).encode_to_vec(),
    }
}

pub(crate) fn compressed_image_schema() -> ProtoSchema {
    let message = DescriptorProto {
        name: Some("CompressedImage".into()),
        field: vec![
            field("timestamp", 1, Type::Message, Some(TIMESTAMP_TYPE)),
            field("frame_id", 4, Type::String, None),
            field("data", 2, Type::Bytes, None),
            field("format", 3, Type::String, None),
        ],
        ..Default::default()
    };
    ProtoSchema {
        name: "foxglove.CompressedImage",
        descriptor_set: foxglove_file("foxglove/CompressedImage.proto", message).encode_to_vec(),
    }
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
    ProtoSchema {
        name: "foxglove.Log",
        descriptor_set: foxglove_file("foxglove/Log.proto", message).encode_to_vec(),
    }
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
        assert_eq!(json_name("frame_id"), "frameId");
    }

    #[test]
    fn timestamps_split_seconds_and_nanoseconds() {
        let t = timestamp(1_700_000_000_123_456_789);
        assert_eq!((t.seconds, t.nanos), (1_700_000_000, 123_456_789));
    }
}
