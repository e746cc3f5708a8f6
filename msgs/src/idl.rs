//! ROS 2 `.msg` / `.srv` parsing and RIHS01 type hashes (REP-2011).
//!
//! The hash is the SHA-256 of a canonical JSON rendering of the type description (the type and every
//! type it references, sorted by name; constants and default values excluded), exactly as
//! `rosidl_generator_type_description` computes it. The IDL sources are embedded from `msgs/ros/`,
//! so the hashes of the project's own types follow their `.msg` files with no hand-kept table.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::OnceLock;

use sha2::{Digest, Sha256};

/// Errors from parsing interface definitions or computing hashes.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum IdlError {
    #[error("{type_name}: line {line}: {reason}")]
    Parse {
        type_name: String,
        line: usize,
        reason: String,
    },
    #[error("unknown interface type `{0}`")]
    UnknownType(String),
}

pub type Result<T> = std::result::Result<T, IdlError>;

/// Element type of a field, in rosidl's IDL vocabulary (`.msg` `float64` is `double`, etc.).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BaseType {
    Primitive(&'static str),
    String {
        bound: Option<u64>,
    },
    WString {
        bound: Option<u64>,
    },
    /// Fully qualified `pkg/msg/Name`.
    Nested(String),
}

/// Container around the element type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Container {
    Single,
    Array(u64),
    BoundedSequence(u64),
    UnboundedSequence,
}

/// One field of a message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Field {
    pub name: String,
    pub base: BaseType,
    pub container: Container,
}

/// A parsed message: its fully qualified name and fields (constants dropped: they are not hashed
/// and do not appear on the wire).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MessageDef {
    pub type_name: String,
    pub fields: Vec<Field>,
}

/// `.msg` primitive names mapped to rosidl IDL names and FieldType ids.
const PRIMITIVES: &[(&str, &str, u8)] = &[
    ("bool", "boolean", 15),
    ("byte", "octet", 16),
    ("char", "uint8", 3),
    ("float32", "float", 10),
    ("float64", "double", 11),
    ("int8", "int8", 2),
    ("uint8", "uint8", 3),
    ("int16", "int16", 4),
    ("uint16", "uint16", 5),
    ("int32", "int32", 6),
    ("uint32", "uint32", 7),
    ("int64", "int64", 8),
    ("uint64", "uint64", 9),
];

fn primitive(msg_name: &str) -> Option<(&'static str, u8)> {
    PRIMITIVES
        .iter()
        .find(|(name, _, _)| *name == msg_name)
        .map(|(_, idl, id)| (*idl, *id))
}

fn primitive_id(idl_name: &str) -> u8 {
    PRIMITIVES
        .iter()
        .find(|(_, idl, _)| *idl == idl_name)
        .map_or(0, |(_, _, id)| *id)
}

/// Parse the text of a `.msg` file (or one half of a `.srv`) of package `package`.
pub fn parse_msg(package: &str, type_name: &str, text: &str) -> Result<MessageDef> {
    let mut fields = Vec::new();
    for (index, raw_line) in text.lines().enumerate() {
        let err = |reason: String| IdlError::Parse {
            type_name: type_name.to_owned(),
            line: index + 1,
            reason,
        };
        let line = strip_comment(raw_line).trim();
        if line.is_empty() {
            continue;
        }
        let mut parts = line.split_whitespace();
        let type_token = parts.next().ok_or_else(|| err("empty line".into()))?;
        let rest: String = parts.collect::<Vec<_>>().join(" ");
        // Constants (`TYPE NAME=VALUE`) are neither serialised nor hashed.
        if rest.contains('=') && !type_token.contains('=') {
            let name_part = rest.split('=').next().unwrap_or("").trim();
            if !name_part.contains(' ') {
                continue;
            }
        }
        let name = rest
            .split_whitespace()
            .next()
            .ok_or_else(|| err(format!("field of type `{type_token}` has no name")))?;
        if !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(err(format!("bad field name `{name}`")));
        }
        let (base_token, container) = split_container(type_token).map_err(err)?;
        let base = parse_base(package, base_token).map_err(err)?;
        fields.push(Field {
            name: name.to_owned(),
            base,
            container,
        });
    }
    Ok(MessageDef {
        type_name: type_name.to_owned(),
        fields,
    })
}

fn strip_comment(line: &str) -> &str {
    // A `#` inside a quoted string constant is not a comment; constants are skipped anyway, so
    // cutting at the first `#` outside quotes is enough.
    let mut in_quote: Option<char> = None;
    for (i, c) in line.char_indices() {
        match (c, in_quote) {
            ('"' | '\'', None) => in_quote = Some(c),
            (q, Some(open)) if q == open => in_quote = None,
            ('#', None) => return &line[..i],
            _ => {}
        }
    }
    line
}

fn split_container(token: &str) -> std::result::Result<(&str, Container), String> {
    let Some(open) = token.find('[') else {
        return Ok((token, Container::Single));
    };
    let inner = token[open + 1..]
        .strip_suffix(']')
        .ok_or_else(|| format!("unclosed array bracket in `{token}`"))?;
    let base = &token[..open];
    let container = if inner.is_empty() {
        Container::UnboundedSequence
    } else if let Some(bound) = inner.strip_prefix("<=") {
        Container::BoundedSequence(
            bound
                .parse()
                .map_err(|_| format!("bad sequence bound in `{token}`"))?,
        )
    } else {
        Container::Array(
            inner
                .parse()
                .map_err(|_| format!("bad array size in `{token}`"))?,
        )
    };
    Ok((base, container))
}

fn parse_base(package: &str, token: &str) -> std::result::Result<BaseType, String> {
    if let Some((idl, _)) = primitive(token) {
        return Ok(BaseType::Primitive(idl));
    }
    for (prefix, wide) in [("string", false), ("wstring", true)] {
        if let Some(rest) = token.strip_prefix(prefix) {
            let bound = if rest.is_empty() {
                None
            } else if let Some(b) = rest.strip_prefix("<=") {
                Some(
                    b.parse()
                        .map_err(|_| format!("bad string bound in `{token}`"))?,
                )
            } else {
                continue;
            };
            return Ok(if wide {
                BaseType::WString { bound }
            } else {
                BaseType::String { bound }
            });
        }
    }
    let valid = |s: &str| !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    match token.split('/').collect::<Vec<_>>().as_slice() {
        ["Header"] => Ok(BaseType::Nested("std_msgs/msg/Header".into())),
        [name] if valid(name) => Ok(BaseType::Nested(format!("{package}/msg/{name}"))),
        [pkg, name] if valid(pkg) && valid(name) => {
            Ok(BaseType::Nested(format!("{pkg}/msg/{name}")))
        }
        [pkg, "msg", name] if valid(pkg) && valid(name) => {
            Ok(BaseType::Nested(format!("{pkg}/msg/{name}")))
        }
        _ => Err(format!("unknown type `{token}`")),
    }
}

/// A set of interface definitions, able to compute type hashes.
#[derive(Debug, Default, Clone)]
pub struct Registry {
    messages: BTreeMap<String, MessageDef>,
}

impl Registry {
    /// Add a `.msg` file's text as `package/msg/name`.
    pub fn add_msg(&mut self, package: &str, name: &str, text: &str) -> Result<()> {
        let type_name = format!("{package}/msg/{name}");
        let def = parse_msg(package, &type_name, text)?;
        self.messages.insert(type_name, def);
        Ok(())
    }

    /// Add a `.srv` file's text as `package/srv/name`, with the request, response and event
    /// messages rosidl generates for it.
    pub fn add_srv(&mut self, package: &str, name: &str, text: &str) -> Result<()> {
        let srv = format!("{package}/srv/{name}");
        let (request_text, response_text) = split_srv(text);
        let request = format!("{srv}_Request");
        let response = format!("{srv}_Response");
        let event = format!("{srv}_Event");
        for (type_name, part) in [(&request, request_text), (&response, response_text)] {
            let def = parse_msg(package, type_name, part)?;
            self.messages.insert(type_name.clone(), def);
        }
        let nested = |name: &str, type_name: &str, container| Field {
            name: name.into(),
            base: BaseType::Nested(type_name.into()),
            container,
        };
        self.messages.insert(
            event.clone(),
            MessageDef {
                type_name: event.clone(),
                fields: vec![
                    nested(
                        "info",
                        "service_msgs/msg/ServiceEventInfo",
                        Container::Single,
                    ),
                    nested("request", &request, Container::BoundedSequence(1)),
                    nested("response", &response, Container::BoundedSequence(1)),
                ],
            },
        );
        self.messages.insert(
            srv.clone(),
            MessageDef {
                type_name: srv,
                fields: vec![
                    nested("request_message", &request, Container::Single),
                    nested("response_message", &response, Container::Single),
                    nested("event_message", &event, Container::Single),
                ],
            },
        );
        Ok(())
    }

    /// The parsed definition of a type (`pkg/msg/Name`, `pkg/srv/Name_Request`, ...).
    pub fn get(&self, type_name: &str) -> Result<&MessageDef> {
        self.messages
            .get(type_name)
            .ok_or_else(|| IdlError::UnknownType(type_name.to_owned()))
    }

    /// Every type name in the registry.
    pub fn type_names(&self) -> impl Iterator<Item = &str> {
        self.messages.keys().map(String::as_str)
    }

    /// The canonical JSON that RIHS01 hashes (no default values).
    pub fn hashable_json(&self, type_name: &str) -> Result<String> {
        let top = self.get(type_name)?;
        let mut referenced = BTreeSet::new();
        let mut queue: Vec<&str> = nested_names(top).collect();
        while let Some(name) = queue.pop() {
            if referenced.insert(name.to_owned()) {
                queue.extend(nested_names(self.get(name)?));
            }
        }
        let mut json = String::from("{\"type_description\": ");
        write_description(&mut json, top);
        json.push_str(", \"referenced_type_descriptions\": [");
        for (i, name) in referenced.iter().enumerate() {
            if i > 0 {
                json.push_str(", ");
            }
            write_description(&mut json, self.get(name)?);
        }
        json.push_str("]}");
        Ok(json)
    }

    /// The RIHS01 hash string, e.g. `RIHS01_d31d41a9...` for `sensor_msgs/msg/Image`.
    pub fn type_hash(&self, type_name: &str) -> Result<String> {
        let json = self.hashable_json(type_name)?;
        Ok(format!("RIHS01_{}", hex::encode(Sha256::digest(json))))
    }
}

fn split_srv(text: &str) -> (&str, &str) {
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        if line.trim() == "---" {
            return (&text[..offset], &text[offset + line.len()..]);
        }
        offset += line.len();
    }
    (text, "")
}

fn nested_names(def: &MessageDef) -> impl Iterator<Item = &str> {
    def.fields.iter().filter_map(|f| match &f.base {
        BaseType::Nested(name) => Some(name.as_str()),
        _ => None,
    })
}

fn write_description(out: &mut String, def: &MessageDef) {
    out.push_str("{\"type_name\": ");
    push_json_string(out, &def.type_name);
    out.push_str(", \"fields\": [");
    let placeholder;
    let fields: &[Field] = if def.fields.is_empty() {
        // rosidl gives empty structures one dummy member.
        placeholder = [Field {
            name: "structure_needs_at_least_one_member".into(),
            base: BaseType::Primitive("uint8"),
            container: Container::Single,
        }];
        &placeholder
    } else {
        &def.fields
    };
    for (i, field) in fields.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        let (type_id, capacity, string_capacity, nested) = field_type(field);
        out.push_str("{\"name\": ");
        push_json_string(out, &field.name);
        out.push_str(&format!(
            ", \"type\": {{\"type_id\": {type_id}, \"capacity\": {capacity}, \"string_capacity\": {string_capacity}, \"nested_type_name\": "
        ));
        push_json_string(out, nested);
        out.push_str("}}");
    }
    out.push_str("]}");
}

fn field_type(field: &Field) -> (u32, u64, u64, &str) {
    let (value_id, string_capacity, nested) = match &field.base {
        BaseType::Primitive(idl) => (u32::from(primitive_id(idl)), 0, ""),
        BaseType::String { bound: None } => (17, 0, ""),
        BaseType::WString { bound: None } => (18, 0, ""),
        BaseType::String { bound: Some(b) } => (21, *b, ""),
        BaseType::WString { bound: Some(b) } => (22, *b, ""),
        BaseType::Nested(name) => (1, 0, name.as_str()),
    };
    let (offset, capacity) = match field.container {
        Container::Single => (0, 0),
        Container::Array(n) => (48, n),
        Container::BoundedSequence(n) => (96, n),
        Container::UnboundedSequence => (144, 0),
    };
    (value_id + offset, capacity, string_capacity, nested)
}

fn push_json_string(out: &mut String, s: &str) {
    // Python's json.dumps with ensure_ascii=True.
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if (c as u32) < 0x20 || (c as u32) > 0x7e => {
                let mut buf = [0u16; 2];
                for unit in c.encode_utf16(&mut buf) {
                    out.push_str(&format!("\\u{unit:04x}"));
                }
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

macro_rules! embedded {
    ($($kind:ident $pkg:literal $name:literal => $path:literal;)*) => {
        /// Every `.msg` / `.srv` this crate embeds, as (kind, package, name, text).
        pub const EMBEDDED: &[(&str, &str, &str, &str)] = &[
            $((stringify!($kind), $pkg, $name, include_str!(concat!("../ros/", $path))),)*
        ];
    };
}

embedded! {
    msg "builtin_interfaces" "Time" => "upstream/builtin_interfaces/msg/Time.msg";
    msg "builtin_interfaces" "Duration" => "upstream/builtin_interfaces/msg/Duration.msg";
    msg "std_msgs" "Header" => "upstream/std_msgs/msg/Header.msg";
    msg "std_msgs" "ColorRGBA" => "upstream/std_msgs/msg/ColorRGBA.msg";
    msg "std_msgs" "String" => "upstream/std_msgs/msg/String.msg";
    msg "geometry_msgs" "Point" => "upstream/geometry_msgs/msg/Point.msg";
    msg "geometry_msgs" "Pose" => "upstream/geometry_msgs/msg/Pose.msg";
    msg "geometry_msgs" "PoseWithCovariance" => "upstream/geometry_msgs/msg/PoseWithCovariance.msg";
    msg "geometry_msgs" "Quaternion" => "upstream/geometry_msgs/msg/Quaternion.msg";
    msg "geometry_msgs" "Transform" => "upstream/geometry_msgs/msg/Transform.msg";
    msg "geometry_msgs" "TransformStamped" => "upstream/geometry_msgs/msg/TransformStamped.msg";
    msg "geometry_msgs" "Vector3" => "upstream/geometry_msgs/msg/Vector3.msg";
    msg "sensor_msgs" "Image" => "upstream/sensor_msgs/msg/Image.msg";
    msg "sensor_msgs" "CompressedImage" => "upstream/sensor_msgs/msg/CompressedImage.msg";
    msg "sensor_msgs" "CameraInfo" => "upstream/sensor_msgs/msg/CameraInfo.msg";
    msg "sensor_msgs" "RegionOfInterest" => "upstream/sensor_msgs/msg/RegionOfInterest.msg";
    msg "sensor_msgs" "PointCloud2" => "upstream/sensor_msgs/msg/PointCloud2.msg";
    msg "sensor_msgs" "PointField" => "upstream/sensor_msgs/msg/PointField.msg";
    msg "tf2_msgs" "TFMessage" => "upstream/tf2_msgs/msg/TFMessage.msg";
    msg "vision_msgs" "Detection3D" => "upstream/vision_msgs/msg/Detection3D.msg";
    msg "vision_msgs" "Detection3DArray" => "upstream/vision_msgs/msg/Detection3DArray.msg";
    msg "vision_msgs" "ObjectHypothesisWithPose" => "upstream/vision_msgs/msg/ObjectHypothesisWithPose.msg";
    msg "vision_msgs" "ObjectHypothesis" => "upstream/vision_msgs/msg/ObjectHypothesis.msg";
    msg "vision_msgs" "BoundingBox3D" => "upstream/vision_msgs/msg/BoundingBox3D.msg";
    msg "visualization_msgs" "Marker" => "upstream/visualization_msgs/msg/Marker.msg";
    msg "visualization_msgs" "MarkerArray" => "upstream/visualization_msgs/msg/MarkerArray.msg";
    msg "visualization_msgs" "MeshFile" => "upstream/visualization_msgs/msg/MeshFile.msg";
    msg "visualization_msgs" "UVCoordinate" => "upstream/visualization_msgs/msg/UVCoordinate.msg";
    msg "service_msgs" "ServiceEventInfo" => "upstream/service_msgs/msg/ServiceEventInfo.msg";
    msg "groupforward_msgs" "Instance" => "groupforward_msgs/msg/Instance.msg";
    msg "groupforward_msgs" "InstanceArray" => "groupforward_msgs/msg/InstanceArray.msg";
    msg "groupforward_msgs" "InstanceMasks" => "groupforward_msgs/msg/InstanceMasks.msg";
    msg "groupforward_msgs" "NodeView" => "groupforward_msgs/msg/NodeView.msg";
    msg "groupforward_msgs" "SceneGraphNode" => "groupforward_msgs/msg/SceneGraphNode.msg";
    msg "groupforward_msgs" "EdgeView" => "groupforward_msgs/msg/EdgeView.msg";
    msg "groupforward_msgs" "SceneGraphEdge" => "groupforward_msgs/msg/SceneGraphEdge.msg";
    msg "groupforward_msgs" "SceneGraph" => "groupforward_msgs/msg/SceneGraph.msg";
    msg "groupforward_msgs" "Candidate" => "groupforward_msgs/msg/Candidate.msg";
    msg "groupforward_msgs" "CameraStatus" => "groupforward_msgs/msg/CameraStatus.msg";
    msg "groupforward_msgs" "RejectCount" => "groupforward_msgs/msg/RejectCount.msg";
    msg "groupforward_msgs" "StageTiming" => "groupforward_msgs/msg/StageTiming.msg";
    msg "groupforward_msgs" "NodeStatus" => "groupforward_msgs/msg/NodeStatus.msg";
    srv "groupforward_msgs" "Refer" => "groupforward_msgs/srv/Refer.srv";
    srv "groupforward_msgs" "ListInstances" => "groupforward_msgs/srv/ListInstances.srv";
    srv "groupforward_msgs" "GetInstance" => "groupforward_msgs/srv/GetInstance.srv";
    srv "groupforward_msgs" "SaveMap" => "groupforward_msgs/srv/SaveMap.srv";
    srv "groupforward_msgs" "LoadMap" => "groupforward_msgs/srv/LoadMap.srv";
}

/// The registry of every embedded definition, parsed once.
pub fn registry() -> &'static Registry {
    static REGISTRY: OnceLock<Registry> = OnceLock::new();
    REGISTRY.get_or_init(|| {
        let mut registry = Registry::default();
        for (kind, package, name, text) in EMBEDDED {
            let added = if *kind == "srv" {
                registry.add_srv(package, name, text)
            } else {
                registry.add_msg(package, name, text)
            };
            // The embedded files are part of this crate and parsed by its tests.
            if let Err(e) = added {
                panic!("embedded interface definition does not parse: {e}");
            }
        }
        registry
    })
}

/// The full `ros2msg` definition of an embedded message type as `ros2 bag record` stores it in
/// an MCAP schema: the type's own `.msg` text, then every type it references (transitively), each
/// after a separator line of 80 `=` and a `MSG: <package>/msg/<Name>` line. Readers resolve nested
/// types from it without any other definitions at hand.
pub fn message_definition(type_name: &str) -> Result<String> {
    let registry = registry();
    let text_of = |name: &str| {
        EMBEDDED
            .iter()
            .find(|(kind, pkg, msg, _)| *kind == "msg" && format!("{pkg}/msg/{msg}") == name)
            .map(|(_, _, _, text)| *text)
            .ok_or_else(|| IdlError::UnknownType(name.to_owned()))
    };
    let mut referenced = BTreeSet::new();
    let mut queue: Vec<&str> = nested_names(registry.get(type_name)?).collect();
    while let Some(name) = queue.pop() {
        if referenced.insert(name.to_owned()) {
            queue.extend(nested_names(registry.get(name)?));
        }
    }
    let mut out = text_of(type_name)?.trim_end().to_owned();
    for name in &referenced {
        out.push_str(&format!(
            "\n{}\nMSG: {name}\n{}",
            "=".repeat(80),
            text_of(name)?.trim_end()
        ));
    }
    out.push('\n');
    Ok(out)
}

/// RIHS01 hash of an embedded type, e.g. `type_hash("sensor_msgs/msg/Image")`.
pub fn type_hash(type_name: &str) -> Result<String> {
    registry().type_hash(type_name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn message_definition_carries_every_nested_type_once() {
        let full = message_definition("sensor_msgs/msg/Image").unwrap();
        assert!(full.starts_with(
            EMBEDDED
                .iter()
                .find(|e| e.2 == "Image")
                .unwrap()
                .3
                .trim_end()
        ));
        assert_eq!(full.matches("MSG: std_msgs/msg/Header\n").count(), 1);
        assert_eq!(
            full.matches("MSG: builtin_interfaces/msg/Time\n").count(),
            1
        );
        assert_eq!(full.matches("MSG: ").count(), 2);
        let detections = message_definition("vision_msgs/msg/Detection3DArray").unwrap();
        for nested in [
            "Detection3D",
            "BoundingBox3D",
            "PoseWithCovariance",
            "Quaternion",
        ] {
            assert!(detections.contains(&format!("/msg/{nested}\n")), "{nested}");
        }
        assert!(message_definition("nope_msgs/msg/Nope").is_err());
    }

    #[test]
    fn known_upstream_hashes() {
        assert_eq!(
            type_hash("sensor_msgs/msg/Image").unwrap(),
            "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
        );
        assert_eq!(
            type_hash("std_msgs/msg/String").unwrap(),
            "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
        );
    }

    #[test]
    fn known_service_hash() {
        // example_interfaces/srv/AddTwoInts as rmw_zenoh's design document shows it.
        let mut registry = registry().clone();
        registry
            .add_srv(
                "example_interfaces",
                "AddTwoInts",
                "int64 a\nint64 b\n---\nint64 sum\n",
            )
            .unwrap();
        assert_eq!(
            registry
                .type_hash("example_interfaces/srv/AddTwoInts")
                .unwrap(),
            "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
        );
    }

    #[test]
    fn every_embedded_type_hashes() {
        for name in registry().type_names() {
            let hash = type_hash(name).unwrap();
            assert_eq!(hash.len(), "RIHS01_".len() + 64, "{name}");
        }
    }

    #[test]
    fn parses_containers_bounds_constants_and_defaults() {
        let text = "uint8 A=1 # constant\nstring<=5 s\nfloat64[9] k\nint32[<=3] b\nPoint[] p\nbyte x 7\nstring C = \"a#b\"\n";
        let def = parse_msg("geometry_msgs", "geometry_msgs/msg/T", text).unwrap();
        let names: Vec<_> = def.fields.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["s", "k", "b", "p", "x"]);
        assert_eq!(def.fields[0].base, BaseType::String { bound: Some(5) });
        assert_eq!(def.fields[1].container, Container::Array(9));
        assert_eq!(def.fields[2].container, Container::BoundedSequence(3));
        assert_eq!(
            def.fields[3].base,
            BaseType::Nested("geometry_msgs/msg/Point".into())
        );
        assert_eq!(def.fields[4].base, BaseType::Primitive("octet"));
    }

    #[test]
    fn rejects_malformed_definitions() {
        assert!(parse_msg("p", "p/msg/T", "float64[x] k\n").is_err());
        assert!(parse_msg("p", "p/msg/T", "float64\n").is_err());
        assert!(parse_msg("p", "p/msg/T", "a/b/c/d x\n").is_err());
        assert!(matches!(
            type_hash("nope/msg/Nothing"),
            Err(IdlError::UnknownType(_))
        ));
    }

    #[test]
    fn json_escaping_matches_python() {
        let mut out = String::new();
        push_json_string(&mut out, "a\"b\\é");
        assert_eq!(out, "\"a\\\"b\\\\\\u00e9\"");
    }
}
