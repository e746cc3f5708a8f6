//! The message layer against independent references: CDR bytes and RIHS01 hashes written by Python
//! `rosbags` (tests/golden, with the script that made them), and the `.msg` files field by field.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use std::collections::BTreeMap;

use groupforward_msgs::idl::{self, BaseType, Container};
use groupforward_msgs::{cdr, types, RosMessage};
use proptest::prelude::*;
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_reflection::{ContainerFormat, Format, Named, Samples, Tracer, TracerConfig};

const GOLDEN: &str = include_str!("golden/golden.json");

/// Calls `$body` with the Rust type for each ROS type name (`$T` bound to the type).
macro_rules! for_type {
    ($name:expr, $T:ident => $body:expr) => {{
        use groupforward_msgs::types::*;
        match $name {
            "builtin_interfaces/msg/Time" => {
                type $T = builtin_interfaces::Time;
                $body
            }
            "std_msgs/msg/Header" => {
                type $T = std_msgs::Header;
                $body
            }
            "geometry_msgs/msg/Pose" => {
                type $T = geometry_msgs::Pose;
                $body
            }
            "geometry_msgs/msg/TransformStamped" => {
                type $T = geometry_msgs::TransformStamped;
                $body
            }
            "sensor_msgs/msg/Image" => {
                type $T = sensor_msgs::Image;
                $body
            }
            "sensor_msgs/msg/CompressedImage" => {
                type $T = sensor_msgs::CompressedImage;
                $body
            }
            "sensor_msgs/msg/CameraInfo" => {
                type $T = sensor_msgs::CameraInfo;
                $body
            }
            "sensor_msgs/msg/PointCloud2" => {
                type $T = sensor_msgs::PointCloud2;
                $body
            }
            "tf2_msgs/msg/TFMessage" => {
                type $T = tf2_msgs::TFMessage;
                $body
            }
            "vision_msgs/msg/Detection3DArray" => {
                type $T = vision_msgs::Detection3DArray;
                $body
            }
            "visualization_msgs/msg/MarkerArray" => {
                type $T = visualization_msgs::MarkerArray;
                $body
            }
            "groupforward_msgs/msg/InstanceArray" => {
                type $T = gf_msgs::InstanceArray;
                $body
            }
            "groupforward_msgs/msg/InstanceMasks" => {
                type $T = gf_msgs::InstanceMasks;
                $body
            }
            "groupforward_msgs/msg/SceneGraph" => {
                type $T = gf_msgs::SceneGraph;
                $body
            }
            "groupforward_msgs/msg/NodeStatus" => {
                type $T = gf_msgs::NodeStatus;
                $body
            }
            "groupforward_msgs/srv/Refer_Request" => {
                type $T = gf_msgs::ReferRequest;
                $body
            }
            "groupforward_msgs/srv/Refer_Response" => {
                type $T = gf_msgs::ReferResponse;
                $body
            }
            "groupforward_msgs/srv/GetInstance_Response" => {
                type $T = gf_msgs::GetInstanceResponse;
                $body
            }
            other => panic!("golden case for unmapped type {other}"),
        }
    }};
}

fn check_case<T: RosMessage>(bytes: &[u8], expected: &serde_json::Value) {
    let decoded: T = cdr::decode(bytes).unwrap_or_else(|e| panic!("{}: {e}", T::TYPE_NAME));
    assert_eq!(
        &serde_json::to_value(&decoded).unwrap(),
        expected,
        "{}: decoded value differs from rosbags'",
        T::TYPE_NAME
    );
    let encoded = cdr::encode(&decoded).unwrap();
    assert_eq!(encoded, bytes, "{}: re-encoded bytes differ", T::TYPE_NAME);
}

#[test]
fn golden_vectors_from_rosbags_decode_and_reencode_byte_for_byte() {
    let golden: serde_json::Value = serde_json::from_str(GOLDEN).unwrap();
    let cases = golden["cases"].as_array().unwrap();
    assert!(cases.len() >= 15);
    for case in cases {
        let name = case["type"].as_str().unwrap();
        let bytes = hex::decode(case["cdr_hex"].as_str().unwrap()).unwrap();
        for_type!(name, T => check_case::<T>(&bytes, &case["json"]));
    }
}

#[test]
fn type_hashes_match_rosbags() {
    let golden: serde_json::Value = serde_json::from_str(GOLDEN).unwrap();
    let hashes = golden["hashes"].as_object().unwrap();
    assert!(hashes.len() >= 30);
    for (name, expected) in hashes {
        assert_eq!(&idl::type_hash(name).unwrap(), expected, "{name}");
    }
}

/// The serde shape of every Rust message type, traced once.
fn traced() -> BTreeMap<String, ContainerFormat> {
    let mut tracer = Tracer::new(TracerConfig::default());
    let samples = Samples::new();
    macro_rules! trace {
        ($($ty:ty),*) => { $( tracer.trace_type::<$ty>(&samples).unwrap(); )* };
    }
    use types::*;
    trace!(
        sensor_msgs::Image,
        sensor_msgs::CompressedImage,
        sensor_msgs::CameraInfo,
        sensor_msgs::PointCloud2,
        tf2_msgs::TFMessage,
        vision_msgs::Detection3DArray,
        visualization_msgs::MarkerArray,
        std_msgs::String,
        gf_msgs::InstanceArray,
        gf_msgs::InstanceMasks,
        gf_msgs::SceneGraph,
        gf_msgs::NodeStatus,
        gf_msgs::ReferRequest,
        gf_msgs::ReferResponse,
        gf_msgs::ListInstancesRequest,
        gf_msgs::ListInstancesResponse,
        gf_msgs::GetInstanceRequest,
        gf_msgs::GetInstanceResponse,
        gf_msgs::MapPathRequest,
        gf_msgs::MapResultResponse
    );
    tracer.registry().unwrap().into_iter().collect()
}

fn primitive_format(idl_name: &str) -> Format {
    match idl_name {
        "boolean" => Format::Bool,
        "octet" | "uint8" => Format::U8,
        "int8" => Format::I8,
        "int16" => Format::I16,
        "uint16" => Format::U16,
        "int32" => Format::I32,
        "uint32" => Format::U32,
        "int64" => Format::I64,
        "uint64" => Format::U64,
        "float" => Format::F32,
        "double" => Format::F64,
        other => panic!("no serde format for {other}"),
    }
}

/// Serde format a field of this IDL type must have.
fn expected_format(
    base: &BaseType,
    container: Container,
    struct_of: &dyn Fn(&str) -> String,
) -> Format {
    let element = match base {
        BaseType::Primitive(p) => primitive_format(p),
        BaseType::String { .. } => Format::Str,
        BaseType::WString { .. } => panic!("wstring is not used"),
        BaseType::Nested(name) => Format::TypeName(struct_of(name)),
    };
    match container {
        Container::Single => element,
        Container::Array(n) => Format::TupleArray {
            content: Box::new(element),
            size: n as usize,
        },
        Container::UnboundedSequence if element == Format::U8 => Format::Bytes,
        Container::UnboundedSequence | Container::BoundedSequence(_) => {
            Format::Seq(Box::new(element))
        }
    }
}

#[test]
fn rust_types_match_the_idl_field_by_field() {
    let traced = traced();
    // Rust struct name for each ROS type name (Rust names drop the package; service halves are
    // renamed), found through the ROS type names the crate declares.
    let rust_name = |ros: &str| -> String {
        let short = ros.rsplit('/').next().unwrap();
        match short {
            "Refer_Request" => "ReferRequest".into(),
            "Refer_Response" => "ReferResponse".into(),
            "ListInstances_Request" => "ListInstancesRequest".into(),
            "ListInstances_Response" => "ListInstancesResponse".into(),
            "GetInstance_Request" => "GetInstanceRequest".into(),
            "GetInstance_Response" => "GetInstanceResponse".into(),
            "SaveMap_Request" | "LoadMap_Request" => "MapPathRequest".into(),
            "SaveMap_Response" | "LoadMap_Response" => "MapResultResponse".into(),
            other => other.into(),
        }
    };
    let mut checked = 0;
    let registry = idl::registry();
    for ros_name in registry.type_names() {
        if ros_name.ends_with("_Event") || ros_name.contains("/srv/") && !ros_name.contains('_') {
            continue; // generated service wrappers have no Rust struct
        }
        let Some(ContainerFormat::Struct(fields)) = traced.get(&rust_name(ros_name)) else {
            continue; // not reachable from a traced type (e.g. ServiceEventInfo)
        };
        let def = registry.get(ros_name).unwrap();
        let expected: Vec<Named<Format>> = def
            .fields
            .iter()
            .map(|f| Named {
                name: f.name.clone(),
                value: expected_format(&f.base, f.container, &rust_name),
            })
            .collect();
        assert_eq!(fields, &expected, "{ros_name}");
        checked += 1;
    }
    // Every groupforward_msgs type and every standard type the node uses was compared.
    assert!(checked >= 40, "only {checked} types compared");
    for name in types::ALL_TYPE_NAMES {
        assert!(registry.get(name).is_ok(), "{name} has no IDL");
    }
}

fn round_trip<T: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug>(value: &T) {
    let bytes = cdr::encode(value).unwrap();
    let back: T = cdr::decode(&bytes).unwrap();
    assert_eq!(&back, value);
}

fn any_string() -> impl Strategy<Value = String> {
    "[a-zA-Z0-9_ /é]{0,12}"
}

prop_compose! {
    fn any_header()(sec in any::<i32>(), nanosec in 0u32..1_000_000_000, frame_id in any_string())
        -> types::std_msgs::Header {
        types::std_msgs::Header { stamp: types::builtin_interfaces::Time { sec, nanosec }, frame_id }
    }
}

prop_compose! {
    fn any_pose()(p in prop::array::uniform3(-1e6f64..1e6), q in prop::array::uniform4(-1f64..1.0))
        -> types::geometry_msgs::Pose {
        use types::geometry_msgs::*;
        Pose { position: Point { x: p[0], y: p[1], z: p[2] }, orientation: Quaternion { x: q[0], y: q[1], z: q[2], w: q[3] } }
    }
}

prop_compose! {
    fn any_instance()(id in any_string(), label in any_string(), score in 0f64..1.0, pose in any_pose(),
                      point_count in any::<u32>(), visibility in 0f32..1.0, confidence in 0f32..1.0,
                      first in any::<i32>(), last in any::<i32>())
        -> types::gf_msgs::Instance {
        use types::*;
        gf_msgs::Instance {
            id,
            hypotheses: vec![vision_msgs::ObjectHypothesis { class_id: label, score }],
            pose,
            size: geometry_msgs::Vector3 { x: 1.0, y: 2.0, z: 3.0 },
            point_count, visibility, confidence,
            first_seen: builtin_interfaces::Time { sec: first, nanosec: 0 },
            last_seen: builtin_interfaces::Time { sec: last, nanosec: 1 },
        }
    }
}

proptest! {
    #[test]
    fn image_round_trips(header in any_header(), h in 0u32..8, w in 0u32..8, enc in any_string(),
                         data in prop::collection::vec(any::<u8>(), 0..300)) {
        round_trip(&types::sensor_msgs::Image { header, height: h, width: w, encoding: enc, is_bigendian: 0, step: w * 3, data });
    }

    #[test]
    fn compressed_image_round_trips(header in any_header(), format in any_string(),
                                    data in prop::collection::vec(any::<u8>(), 0..300)) {
        round_trip(&types::sensor_msgs::CompressedImage { header, format, data });
    }

    #[test]
    fn camera_info_round_trips(header in any_header(), d in prop::collection::vec(-1f64..1.0, 0..8),
                               k in prop::array::uniform9(-1e3f64..1e3), roi_w in any::<u32>()) {
        let mut info = types::sensor_msgs::CameraInfo { header, d, k, ..Default::default() };
        info.roi.width = roi_w;
        round_trip(&info);
    }

    #[test]
    fn tf_and_cloud_round_trip(header in any_header(), pose in any_pose(), child in any_string(),
                               data in prop::collection::vec(any::<u8>(), 0..64)) {
        use types::*;
        let t = geometry_msgs::TransformStamped {
            header: header.clone(), child_frame_id: child,
            transform: geometry_msgs::Transform {
                translation: geometry_msgs::Vector3 { x: pose.position.x, y: pose.position.y, z: pose.position.z },
                rotation: pose.orientation,
            },
        };
        round_trip(&tf2_msgs::TFMessage { transforms: vec![t.clone(), t] });
        round_trip(&sensor_msgs::PointCloud2 {
            header, height: 1, width: data.len() as u32,
            fields: vec![sensor_msgs::PointField { name: "x".into(), offset: 0, datatype: 7, count: 1 }],
            is_bigendian: false, point_step: 1, row_step: data.len() as u32, data, is_dense: true,
        });
    }

    #[test]
    fn detections_and_markers_round_trip(header in any_header(), pose in any_pose(), id in any_string(),
                                         cov in prop::collection::vec(-1f64..1.0, 36)) {
        use types::*;
        let mut covariance = [0.0; 36];
        covariance.copy_from_slice(&cov);
        round_trip(&vision_msgs::Detection3DArray { header: header.clone(), detections: vec![vision_msgs::Detection3D {
            header: header.clone(),
            results: vec![vision_msgs::ObjectHypothesisWithPose {
                hypothesis: vision_msgs::ObjectHypothesis { class_id: id.clone(), score: 0.5 },
                pose: geometry_msgs::PoseWithCovariance { pose, covariance },
            }],
            bbox: vision_msgs::BoundingBox3D { center: pose, size: geometry_msgs::Vector3 { x: 1.0, y: 1.0, z: 1.0 } },
            id: id.clone(),
        }]});
        round_trip(&visualization_msgs::MarkerArray { markers: vec![visualization_msgs::Marker {
            header, ns: id.clone(), id: 3, pose, text: id, points: vec![geometry_msgs::Point::default(); 2],
            ..Default::default()
        }]});
    }

    #[test]
    fn groupforward_messages_round_trip(header in any_header(), inst in any_instance(),
                                        proto in prop::collection::vec(-1f32..1.0, 0..16),
                                        expr in any_string(), pose in any_pose()) {
        use types::gf_msgs::*;
        round_trip(&InstanceArray { header: header.clone(), instances: vec![inst.clone(), inst.clone()] });
        let node = SceneGraphNode { id: inst.id.clone(), label: "chair".into(), prototype: proto,
            views: vec![NodeView { keyframe_id: "kf".into(), ..Default::default() }], ..Default::default() };
        round_trip(&SceneGraph { header: header.clone(), nodes: vec![node.clone()], edges: vec![SceneGraphEdge {
            source: inst.id.clone(), target: "b".into(), views: vec![EdgeView::default()], ..Default::default() }] });
        round_trip(&InstanceMasks { header: header.clone(), camera: expr.clone(), instance_ids: vec![inst.id.clone()], ..Default::default() });
        round_trip(&NodeStatus { header, uptime_secs: 1.5, cameras: vec![CameraStatus { name: expr.clone(), ..Default::default() }],
            tf_received: 3, tf_rejected: 1, rejections: vec![RejectCount { reason: expr.clone(), count: 2 }],
            stages: vec![StageTiming { stage: expr.clone(), count: 3, last_ms: 1.5, p50_ms: 1.25, p99_ms: 9.0 }] });
        round_trip(&ReferRequest { expression: expr.clone(), use_view_pose: true, view_pose: pose, max_targets: 2, reasoner: String::new() });
        round_trip(&ReferResponse { success: true, instance_ids: vec![inst.id.clone()], confidences: vec![0.5],
            poses: vec![pose], candidates: vec![Candidate { id: inst.id.clone(), ..Default::default() }], ..Default::default() });
        round_trip(&ListInstancesRequest { label_filter: expr.clone() });
        round_trip(&ListInstancesResponse { instances: vec![inst.clone()] });
        round_trip(&GetInstanceRequest { id: expr.clone() });
        round_trip(&GetInstanceResponse { found: true, instance: inst, node });
        round_trip(&MapPathRequest { path: expr.clone() });
        round_trip(&MapResultResponse { success: false, message: expr });
    }

    #[test]
    fn garbage_never_panics(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        use types::*;
        let _ = cdr::decode::<sensor_msgs::Image>(&bytes);
        let _ = cdr::decode::<sensor_msgs::CompressedImage>(&bytes);
        let _ = cdr::decode::<sensor_msgs::CameraInfo>(&bytes);
        let _ = cdr::decode::<tf2_msgs::TFMessage>(&bytes);
        let _ = cdr::decode::<gf_msgs::ReferRequest>(&bytes);
        let _ = cdr::decode::<gf_msgs::ListInstancesRequest>(&bytes);
        let _ = cdr::decode::<gf_msgs::GetInstanceRequest>(&bytes);
        let _ = cdr::decode::<gf_msgs::MapPathRequest>(&bytes);
    }

    #[test]
    fn mutated_valid_messages_never_panic(seed in any::<u64>(), flips in prop::collection::vec((0usize..4096, any::<u8>()), 1..8)) {
        use types::*;
        let image = sensor_msgs::Image { height: 2, width: 2, encoding: "rgb8".into(), step: 6,
            data: vec![(seed % 251) as u8; 12], ..Default::default() };
        let mut bytes = cdr::encode(&image).unwrap();
        for (at, value) in flips {
            let n = bytes.len();
            bytes[at % n] = value;
        }
        let _ = cdr::decode::<sensor_msgs::Image>(&bytes);
    }
}
