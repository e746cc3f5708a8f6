//! Rust types of the ROS 2 messages groupforward reads and writes.
//!
//! Field order is CDR order and follows the `.msg` files under `msgs/ros/` exactly (a test checks
//! this field by field). Byte sequences use `serde_bytes` so that images decode in one copy.

use serde::{Deserialize, Serialize};
use serde_big_array::BigArray;

use crate::RosMessage;

macro_rules! ros_message {
    ($($ty:ty => $name:literal),* $(,)?) => {
        $(impl RosMessage for $ty {
            const TYPE_NAME: &'static str = $name;
        })*
        /// Every Rust message type with its ROS 2 type name (for tests and tools).
        pub const ALL_TYPE_NAMES: &[&str] = &[$($name),*];
    };
}

pub mod builtin_interfaces {
    use super::*;

    #[derive(
        Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default, Serialize, Deserialize,
    )]
    pub struct Time {
        pub sec: i32,
        pub nanosec: u32,
    }

    impl Time {
        /// Nanoseconds since the epoch of this clock.
        pub fn as_nanos(&self) -> i64 {
            i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
        }

        /// The stamp for `nanos` nanoseconds; negative values floor towards the past.
        pub fn from_nanos(nanos: i64) -> Self {
            let sec = nanos.div_euclid(1_000_000_000);
            let nanosec = nanos.rem_euclid(1_000_000_000);
            Self {
                sec: sec.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32,
                nanosec: nanosec as u32,
            }
        }

        pub fn as_secs_f64(&self) -> f64 {
            f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
        }
    }

    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct Duration {
        pub sec: i32,
        pub nanosec: u32,
    }
}

pub mod std_msgs {
    use super::*;
    use crate::types::builtin_interfaces::Time;

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct Header {
        pub stamp: Time,
        pub frame_id: std::string::String,
    }

    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct ColorRGBA {
        pub r: f32,
        pub g: f32,
        pub b: f32,
        pub a: f32,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct String {
        pub data: std::string::String,
    }
}

pub mod geometry_msgs {
    use super::*;
    use crate::types::std_msgs::Header;

    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct Point {
        pub x: f64,
        pub y: f64,
        pub z: f64,
    }

    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct Vector3 {
        pub x: f64,
        pub y: f64,
        pub z: f64,
    }

    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct Quaternion {
        pub x: f64,
        pub y: f64,
        pub z: f64,
        pub w: f64,
    }

    /// The `.msg` default is the identity rotation (w = 1), not all zeros.
    impl Default for Quaternion {
        fn default() -> Self {
            Self {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }
        }
    }

    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct Pose {
        pub position: Point,
        pub orientation: Quaternion,
    }

    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct PoseWithCovariance {
        pub pose: Pose,
        #[serde(with = "BigArray")]
        pub covariance: [f64; 36],
    }

    impl Default for PoseWithCovariance {
        fn default() -> Self {
            Self {
                pose: Pose::default(),
                covariance: [0.0; 36],
            }
        }
    }

    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct Transform {
        pub translation: Vector3,
        pub rotation: Quaternion,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct TransformStamped {
        pub header: Header,
        pub child_frame_id: String,
        pub transform: Transform,
    }
}

pub mod sensor_msgs {
    use super::*;
    use crate::types::std_msgs::Header;

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct Image {
        pub header: Header,
        pub height: u32,
        pub width: u32,
        pub encoding: String,
        pub is_bigendian: u8,
        pub step: u32,
        #[serde(with = "serde_bytes")]
        pub data: Vec<u8>,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct CompressedImage {
        pub header: Header,
        pub format: String,
        #[serde(with = "serde_bytes")]
        pub data: Vec<u8>,
    }

    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct RegionOfInterest {
        pub x_offset: u32,
        pub y_offset: u32,
        pub height: u32,
        pub width: u32,
        pub do_rectify: bool,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct CameraInfo {
        pub header: Header,
        pub height: u32,
        pub width: u32,
        pub distortion_model: String,
        pub d: Vec<f64>,
        pub k: [f64; 9],
        pub r: [f64; 9],
        pub p: [f64; 12],
        pub binning_x: u32,
        pub binning_y: u32,
        pub roi: RegionOfInterest,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct PointField {
        pub name: String,
        pub offset: u32,
        pub datatype: u8,
        pub count: u32,
    }

    impl PointField {
        pub const INT8: u8 = 1;
        pub const UINT8: u8 = 2;
        pub const INT16: u8 = 3;
        pub const UINT16: u8 = 4;
        pub const INT32: u8 = 5;
        pub const UINT32: u8 = 6;
        pub const FLOAT32: u8 = 7;
        pub const FLOAT64: u8 = 8;
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct PointCloud2 {
        pub header: Header,
        pub height: u32,
        pub width: u32,
        pub fields: Vec<PointField>,
        pub is_bigendian: bool,
        pub point_step: u32,
        pub row_step: u32,
        #[serde(with = "serde_bytes")]
        pub data: Vec<u8>,
        pub is_dense: bool,
    }
}

pub mod tf2_msgs {
    use super::*;
    use crate::types::geometry_msgs::TransformStamped;

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct TFMessage {
        pub transforms: Vec<TransformStamped>,
    }
}

pub mod vision_msgs {
    use super::*;
    use crate::types::geometry_msgs::{Pose, PoseWithCovariance, Vector3};
    use crate::types::std_msgs::Header;

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct ObjectHypothesis {
        pub class_id: String,
        pub score: f64,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct ObjectHypothesisWithPose {
        pub hypothesis: ObjectHypothesis,
        pub pose: PoseWithCovariance,
    }

    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct BoundingBox3D {
        pub center: Pose,
        pub size: Vector3,
    }

    /// ROS 2 Jazzy layout: a persistent string `id`, no `source_cloud`.
    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct Detection3D {
        pub header: Header,
        pub results: Vec<ObjectHypothesisWithPose>,
        pub bbox: BoundingBox3D,
        pub id: String,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct Detection3DArray {
        pub header: Header,
        pub detections: Vec<Detection3D>,
    }
}

pub mod visualization_msgs {
    use super::*;
    use crate::types::builtin_interfaces::Duration;
    use crate::types::geometry_msgs::{Point, Pose, Vector3};
    use crate::types::sensor_msgs::CompressedImage;
    use crate::types::std_msgs::{ColorRGBA, Header};

    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct UVCoordinate {
        pub u: f32,
        pub v: f32,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct MeshFile {
        pub filename: String,
        #[serde(with = "serde_bytes")]
        pub data: Vec<u8>,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct Marker {
        pub header: Header,
        pub ns: String,
        pub id: i32,
        #[serde(rename = "type")]
        pub marker_type: i32,
        pub action: i32,
        pub pose: Pose,
        pub scale: Vector3,
        pub color: ColorRGBA,
        pub lifetime: Duration,
        pub frame_locked: bool,
        pub points: Vec<Point>,
        pub colors: Vec<ColorRGBA>,
        pub texture_resource: String,
        pub texture: CompressedImage,
        pub uv_coordinates: Vec<UVCoordinate>,
        pub text: String,
        pub mesh_resource: String,
        pub mesh_file: MeshFile,
        pub mesh_use_embedded_materials: bool,
    }

    impl Marker {
        pub const ARROW: i32 = 0;
        pub const CUBE: i32 = 1;
        pub const SPHERE: i32 = 2;
        pub const CYLINDER: i32 = 3;
        pub const LINE_STRIP: i32 = 4;
        pub const LINE_LIST: i32 = 5;
        pub const TEXT_VIEW_FACING: i32 = 9;
        pub const ADD: i32 = 0;
        pub const DELETE: i32 = 2;
        pub const DELETEALL: i32 = 3;
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct MarkerArray {
        pub markers: Vec<Marker>,
    }
}

/// The project's own interfaces (`msgs/ros/groupforward_msgs`).
pub mod gf_msgs {
    use super::*;
    use crate::types::builtin_interfaces::Time;
    use crate::types::geometry_msgs::{Point, Pose, Vector3};
    use crate::types::sensor_msgs::{Image, PointCloud2};
    use crate::types::std_msgs::Header;
    use crate::types::vision_msgs::{BoundingBox3D, ObjectHypothesis};

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct Instance {
        pub id: String,
        pub hypotheses: Vec<ObjectHypothesis>,
        pub pose: Pose,
        pub size: Vector3,
        pub point_count: u32,
        pub visibility: f32,
        pub confidence: f32,
        pub first_seen: Time,
        pub last_seen: Time,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct InstanceArray {
        pub header: Header,
        pub instances: Vec<Instance>,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct InstanceMasks {
        pub header: Header,
        pub camera: String,
        pub mask: Image,
        pub instance_ids: Vec<String>,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct NodeView {
        pub keyframe_id: String,
        pub x_min: f32,
        pub y_min: f32,
        pub x_max: f32,
        pub y_max: f32,
        pub visibility: f32,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct SceneGraphNode {
        pub id: String,
        pub label: String,
        pub prototype: Vec<f32>,
        pub center: Point,
        pub extent: Vector3,
        pub volume: f64,
        pub views: Vec<NodeView>,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct EdgeView {
        pub keyframe_id: String,
        pub projected_distance: f32,
        pub direction: f32,
        pub overlap: f32,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct SceneGraphEdge {
        pub source: String,
        pub target: String,
        pub distance: f64,
        pub height_difference: f64,
        pub size_ratio: f64,
        pub views: Vec<EdgeView>,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct SceneGraph {
        pub header: Header,
        pub nodes: Vec<SceneGraphNode>,
        pub edges: Vec<SceneGraphEdge>,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct Candidate {
        pub id: String,
        pub label: String,
        pub score: f32,
        pub semantic_score: f32,
        pub geometric_score: f32,
        pub visibility_score: f32,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct CameraStatus {
        pub name: String,
        pub frames_received: u64,
        pub frames_synced: u64,
        pub frames_rejected: u64,
        pub rate_hz: f32,
        pub last_stamp: Time,
        pub depth_pixels: u64,
        pub depth_pixels_invalid: u64,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct RejectCount {
        pub reason: String,
        pub count: u64,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct StageTiming {
        pub stage: String,
        pub count: u64,
        pub last_ms: f64,
        pub p50_ms: f64,
        pub p99_ms: f64,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct NodeStatus {
        pub header: Header,
        pub uptime_secs: f64,
        pub cameras: Vec<CameraStatus>,
        pub tf_received: u64,
        pub tf_rejected: u64,
        pub rejections: Vec<RejectCount>,
        pub stages: Vec<StageTiming>,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct ReferRequest {
        pub expression: String,
        pub use_view_pose: bool,
        pub view_pose: Pose,
        pub max_targets: u32,
        pub reasoner: String,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct ReferResponse {
        pub success: bool,
        pub message: String,
        pub instance_ids: Vec<String>,
        pub confidences: Vec<f32>,
        pub poses: Vec<Pose>,
        pub boxes: Vec<BoundingBox3D>,
        pub target_cloud: PointCloud2,
        pub view_masks: Vec<InstanceMasks>,
        pub candidates: Vec<Candidate>,
        pub reasoner_used: String,
        pub trace: String,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct ListInstancesRequest {
        pub label_filter: String,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct ListInstancesResponse {
        pub instances: Vec<Instance>,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct GetInstanceRequest {
        pub id: String,
    }

    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct GetInstanceResponse {
        pub found: bool,
        pub instance: Instance,
        pub node: SceneGraphNode,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct MapPathRequest {
        pub path: String,
    }

    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct MapResultResponse {
        pub success: bool,
        pub message: String,
    }
}

/// A ROS 2 service: its type name and request / response types.
pub trait RosService {
    const TYPE_NAME: &'static str;
    type Request: RosMessage;
    type Response: RosMessage;
}

macro_rules! ros_service {
    ($($svc:ident => $name:literal : $req:ty, $resp:ty;)*) => {
        $(
            #[derive(Debug, Clone, Copy)]
            pub struct $svc;
            impl RosService for $svc {
                const TYPE_NAME: &'static str = $name;
                type Request = $req;
                type Response = $resp;
            }
        )*
    };
}

/// Service markers of `groupforward_msgs/srv`.
pub mod services {
    use super::gf_msgs::*;
    use super::RosService;

    ros_service! {
        Refer => "groupforward_msgs/srv/Refer": ReferRequest, ReferResponse;
        ListInstances => "groupforward_msgs/srv/ListInstances": ListInstancesRequest, ListInstancesResponse;
        GetInstance => "groupforward_msgs/srv/GetInstance": GetInstanceRequest, GetInstanceResponse;
        SaveMap => "groupforward_msgs/srv/SaveMap": MapPathRequest, MapResultResponse;
        LoadMap => "groupforward_msgs/srv/LoadMap": MapPathRequest, MapResultResponse;
    }
}

// SaveMap and LoadMap share their request / response layouts; their `_Request` type names differ
// only in the IDL, so the Rust types carry SaveMap's names and the wire format is identical.
ros_message! {
    builtin_interfaces::Time => "builtin_interfaces/msg/Time",
    builtin_interfaces::Duration => "builtin_interfaces/msg/Duration",
    std_msgs::Header => "std_msgs/msg/Header",
    std_msgs::ColorRGBA => "std_msgs/msg/ColorRGBA",
    std_msgs::String => "std_msgs/msg/String",
    geometry_msgs::Point => "geometry_msgs/msg/Point",
    geometry_msgs::Vector3 => "geometry_msgs/msg/Vector3",
    geometry_msgs::Quaternion => "geometry_msgs/msg/Quaternion",
    geometry_msgs::Pose => "geometry_msgs/msg/Pose",
    geometry_msgs::PoseWithCovariance => "geometry_msgs/msg/PoseWithCovariance",
    geometry_msgs::Transform => "geometry_msgs/msg/Transform",
    geometry_msgs::TransformStamped => "geometry_msgs/msg/TransformStamped",
    sensor_msgs::Image => "sensor_msgs/msg/Image",
    sensor_msgs::CompressedImage => "sensor_msgs/msg/CompressedImage",
    sensor_msgs::RegionOfInterest => "sensor_msgs/msg/RegionOfInterest",
    sensor_msgs::CameraInfo => "sensor_msgs/msg/CameraInfo",
    sensor_msgs::PointField => "sensor_msgs/msg/PointField",
    sensor_msgs::PointCloud2 => "sensor_msgs/msg/PointCloud2",
    tf2_msgs::TFMessage => "tf2_msgs/msg/TFMessage",
    vision_msgs::ObjectHypothesis => "vision_msgs/msg/ObjectHypothesis",
    vision_msgs::ObjectHypothesisWithPose => "vision_msgs/msg/ObjectHypothesisWithPose",
    vision_msgs::BoundingBox3D => "vision_msgs/msg/BoundingBox3D",
    vision_msgs::Detection3D => "vision_msgs/msg/Detection3D",
    vision_msgs::Detection3DArray => "vision_msgs/msg/Detection3DArray",
    visualization_msgs::UVCoordinate => "visualization_msgs/msg/UVCoordinate",
    visualization_msgs::MeshFile => "visualization_msgs/msg/MeshFile",
    visualization_msgs::Marker => "visualization_msgs/msg/Marker",
    visualization_msgs::MarkerArray => "visualization_msgs/msg/MarkerArray",
    gf_msgs::Instance => "groupforward_msgs/msg/Instance",
    gf_msgs::InstanceArray => "groupforward_msgs/msg/InstanceArray",
    gf_msgs::InstanceMasks => "groupforward_msgs/msg/InstanceMasks",
    gf_msgs::NodeView => "groupforward_msgs/msg/NodeView",
    gf_msgs::SceneGraphNode => "groupforward_msgs/msg/SceneGraphNode",
    gf_msgs::EdgeView => "groupforward_msgs/msg/EdgeView",
    gf_msgs::SceneGraphEdge => "groupforward_msgs/msg/SceneGraphEdge",
    gf_msgs::SceneGraph => "groupforward_msgs/msg/SceneGraph",
    gf_msgs::Candidate => "groupforward_msgs/msg/Candidate",
    gf_msgs::CameraStatus => "groupforward_msgs/msg/CameraStatus",
    gf_msgs::RejectCount => "groupforward_msgs/msg/RejectCount",
    gf_msgs::StageTiming => "groupforward_msgs/msg/StageTiming",
    gf_msgs::NodeStatus => "groupforward_msgs/msg/NodeStatus",
    gf_msgs::ReferRequest => "groupforward_msgs/srv/Refer_Request",
    gf_msgs::ReferResponse => "groupforward_msgs/srv/Refer_Response",
    gf_msgs::ListInstancesRequest => "groupforward_msgs/srv/ListInstances_Request",
    gf_msgs::ListInstancesResponse => "groupforward_msgs/srv/ListInstances_Response",
    gf_msgs::GetInstanceRequest => "groupforward_msgs/srv/GetInstance_Request",
    gf_msgs::GetInstanceResponse => "groupforward_msgs/srv/GetInstance_Response",
    gf_msgs::MapPathRequest => "groupforward_msgs/srv/SaveMap_Request",
    gf_msgs::MapResultResponse => "groupforward_msgs/srv/SaveMap_Response",
}
