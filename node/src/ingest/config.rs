//! Ingest's sections of the node config: cameras (topics per camera), TF and the sync bounds.

use serde::{Deserialize, Serialize};

pub const DEFAULT_WORLD_FRAME: &str = "map";
pub const DEFAULT_TF_TOPIC: &str = "/tf";
pub const DEFAULT_TF_STATIC_TOPIC: &str = "/tf_static";
pub const DEFAULT_SYNC_TOLERANCE_SECS: f64 = 0.02;
pub const DEFAULT_MAX_POSE_WAIT_SECS: f64 = 0.5;
pub const DEFAULT_QUEUE_DEPTH: usize = 64;
pub const DEFAULT_PENDING_FRAMES: usize = 8;
pub const DEFAULT_MAX_IMAGE_SIDE: u32 = 8192;
pub const DEFAULT_TF_HISTORY_SECS: f64 = 10.0;
/// Depth outside this range (metres) is invalid: closer than any consumer depth camera's minimum
/// range, farther than its useful one.
pub const DEFAULT_DEPTH_RANGE_M: [f32; 2] = [0.1, 10.0];
/// A depth pixel none of whose 4-neighbours lies within this relative difference is an isolated
/// (flying) measurement.
pub const DEFAULT_ISOLATED_DEPTH_RATIO: f32 = 0.1;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ImageTransport {
    /// `sensor_msgs/Image`.
    #[default]
    Raw,
    /// `sensor_msgs/CompressedImage` (jpeg / png).
    Compressed,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    pub name: String,
    pub image_topic: String,
    pub transport: ImageTransport,
    pub camera_info_topic: String,
    /// Optional depth image (16UC1 in mm or 32FC1 in m), registered to the colour image.
    pub depth_topic: Option<String>,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            name: "front".into(),
            image_topic: "/camera/color/image_raw".into(),
            transport: ImageTransport::Raw,
            camera_info_topic: "/camera/color/camera_info".into(),
            depth_topic: Some("/camera/depth/image_raw".into()),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TfSection {
    pub topic: String,
    pub static_topic: String,
    /// Fixed frame that poses and the map are expressed in (REP-105).
    pub world_frame: String,
    /// How long dynamic transforms are kept for lookups by stamp.
    pub history_secs: f64,
}

impl Default for TfSection {
    fn default() -> Self {
        Self {
            topic: DEFAULT_TF_TOPIC.into(),
            static_topic: DEFAULT_TF_STATIC_TOPIC.into(),
            world_frame: DEFAULT_WORLD_FRAME.into(),
            history_secs: DEFAULT_TF_HISTORY_SECS,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IngestSection {
    /// Largest stamp difference between a colour image and its depth image.
    pub sync_tolerance_secs: f64,
    /// How long (in stamp time, against the newest TF) a frame may wait for its pose.
    pub max_pose_wait_secs: f64,
    /// Bound of the incoming message queue; when full the oldest message is dropped and counted.
    pub queue_depth: usize,
    /// Frames per camera waiting for depth or a pose.
    pub pending_frames: usize,
    /// Images wider or taller than this are rejected as absurd.
    pub max_image_side: u32,
    /// Valid depth range [near, far] in metres; depth outside it is marked invalid.
    pub depth_range_m: [f32; 2],
    /// Relative depth difference within which a 4-neighbour agrees; a depth pixel with no
    /// agreeing neighbour is marked invalid (0 switches the check off).
    pub isolated_depth_ratio: f32,
}

impl Default for IngestSection {
    fn default() -> Self {
        Self {
            sync_tolerance_secs: DEFAULT_SYNC_TOLERANCE_SECS,
            max_pose_wait_secs: DEFAULT_MAX_POSE_WAIT_SECS,
            queue_depth: DEFAULT_QUEUE_DEPTH,
            pending_frames: DEFAULT_PENDING_FRAMES,
            max_image_side: DEFAULT_MAX_IMAGE_SIDE,
            depth_range_m: DEFAULT_DEPTH_RANGE_M,
            isolated_depth_ratio: DEFAULT_ISOLATED_DEPTH_RATIO,
        }
    }
}
