//! Node configuration: one YAML file (`launch/groupforward.yaml` is the commented default), parsed
//! into serde structs that reject unknown keys, with every default a named constant.

use std::path::Path;

use serde::{Deserialize, Serialize};

pub const DEFAULT_NODE_NAME: &str = "groupforward";
pub const DEFAULT_NAMESPACE: &str = "/";
pub const DEFAULT_DOMAIN_ID: u32 = 0;
pub const DEFAULT_WORLD_FRAME: &str = "map";
pub const DEFAULT_TF_TOPIC: &str = "/tf";
pub const DEFAULT_TF_STATIC_TOPIC: &str = "/tf_static";
pub const DEFAULT_SYNC_TOLERANCE_SECS: f64 = 0.02;
pub const DEFAULT_MAX_POSE_WAIT_SECS: f64 = 0.5;
pub const DEFAULT_QUEUE_DEPTH: usize = 64;
pub const DEFAULT_PENDING_FRAMES: usize = 8;
pub const DEFAULT_MAX_IMAGE_SIDE: u32 = 8192;
pub const DEFAULT_STATUS_PERIOD_SECS: f64 = 1.0;
pub const DEFAULT_TF_HISTORY_SECS: f64 = 10.0;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("invalid config {path}: {source}")]
    Parse {
        path: String,
        source: serde_yaml_ng::Error,
    },
    #[error("invalid config: {0}")]
    Invalid(String),
}

pub type Result<T> = std::result::Result<T, ConfigError>;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub node: NodeSection,
    pub zenoh: ZenohSection,
    pub cameras: Vec<CameraConfig>,
    pub tf: TfSection,
    pub ingest: IngestSection,
    pub status: StatusSection,
    pub models: ModelsSection,
    pub window: crate::window::WindowSection,
    pub map: MapSection,
    pub semantics: SemanticsSection,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            node: NodeSection::default(),
            zenoh: ZenohSection::default(),
            cameras: vec![CameraConfig::default()],
            tf: TfSection::default(),
            ingest: IngestSection::default(),
            status: StatusSection::default(),
            models: ModelsSection::default(),
            window: crate::window::WindowSection::default(),
            map: MapSection::default(),
            semantics: SemanticsSection::default(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NodeSection {
    pub name: String,
    /// Absolute ROS namespace; also names the JSON API prefix (`groupforward/<namespace>/...`).
    pub namespace: String,
}

impl Default for NodeSection {
    fn default() -> Self {
        Self {
            name: DEFAULT_NODE_NAME.into(),
            namespace: DEFAULT_NAMESPACE.into(),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ZenohMode {
    #[default]
    Peer,
    Client,
    Router,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohSection {
    pub mode: ZenohMode,
    /// Endpoints to listen on, e.g. `tcp/0.0.0.0:7447`.
    pub listen: Vec<String>,
    /// Endpoints to connect to, e.g. the rmw_zenoh router `tcp/localhost:7447`.
    pub connect: Vec<String>,
    /// Off by default: robots on shared networks should not discover each other by accident.
    pub multicast_scouting: bool,
    /// ROS_DOMAIN_ID, the first chunk of every rmw_zenoh key.
    pub domain_id: u32,
}

impl Default for ZenohSection {
    fn default() -> Self {
        Self {
            mode: ZenohMode::Peer,
            listen: Vec::new(),
            connect: vec!["tcp/localhost:7447".into()],
            multicast_scouting: false,
            domain_id: DEFAULT_DOMAIN_ID,
        }
    }
}

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
}

impl Default for IngestSection {
    fn default() -> Self {
        Self {
            sync_tolerance_secs: DEFAULT_SYNC_TOLERANCE_SECS,
            max_pose_wait_secs: DEFAULT_MAX_POSE_WAIT_SECS,
            queue_depth: DEFAULT_QUEUE_DEPTH,
            pending_frames: DEFAULT_PENDING_FRAMES,
            max_image_side: DEFAULT_MAX_IMAGE_SIDE,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StatusSection {
    pub period_secs: f64,
}

impl Default for StatusSection {
    fn default() -> Self {
        Self {
            period_secs: DEFAULT_STATUS_PERIOD_SECS,
        }
    }
}

/// The persistent instance map: where `~/save_map` and `~/load_map` write and read by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapSection {
    /// Snapshot file; `null`: services need an explicit path and nothing is restored.
    pub file: Option<String>,
    /// Load `file` at start when it exists (a corrupt or newer file is logged; the map starts empty).
    pub restore_on_start: bool,
}

impl Default for MapSection {
    fn default() -> Self {
        Self {
            file: None,
            restore_on_start: true,
        }
    }
}

/// How instances are named: hypotheses from the semantic prototype against a vocabulary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SemanticsSection {
    /// Phrases instances are named with (ObjectHypothesis class_id), embedded by the text encoder;
    /// any words work. `other` catches walls, floor and unnamed things.
    pub vocabulary: Vec<String>,
    /// τ of the softmax over the vocabulary's cosines that gives hypothesis scores.
    pub temperature: f32,
    /// Hypotheses per instance, best first.
    pub hypotheses: usize,
}

/// What walls, floor and anything unnamed are called (the semantic model's explicit `other` class).
pub const OTHER_PHRASE: &str = "other";

/// The simulator's object classes (ScanNet names) and `other`: what the shipped semantic model
/// was trained on.
pub fn default_vocabulary() -> Vec<String> {
    groupforward_sim::library::classes()
        .iter()
        .map(|c| c.name.to_owned())
        .chain([OTHER_PHRASE.to_owned()])
        .collect()
}
pub const DEFAULT_SEMANTIC_TEMPERATURE: f32 = 0.05;
pub const DEFAULT_HYPOTHESES: usize = 3;

impl Default for SemanticsSection {
    fn default() -> Self {
        Self {
            vocabulary: default_vocabulary(),
            temperature: DEFAULT_SEMANTIC_TEMPERATURE,
            hypotheses: DEFAULT_HYPOTHESES,
        }
    }
}

pub const DEFAULT_TEXT_ENCODER: &str = "models/all-MiniLM-L6-v2.toml";
pub const DEFAULT_RECONSTRUCTION: &str = "models/groupforward-mini-rgbd.toml";
pub const DEFAULT_SEMANTIC: &str = "models/semantic-mini.toml";
pub const DEFAULT_MODEL_THREADS: usize = 2;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelsSection {
    /// ONNX Runtime library; null: `ORT_DYLIB_PATH`, then the project's `.venv` (`make setup`).
    pub onnxruntime: Option<std::path::PathBuf>,
    /// Execution provider: cpu, cuda or tensorrt (GPU providers need the matching cargo feature).
    pub provider: crate::model::Provider,
    /// ONNX Runtime intra-op threads per model.
    pub threads: usize,
    /// Text encoder manifest (relative paths resolve against the working directory).
    pub text_encoder: std::path::PathBuf,
    /// Reconstruction model manifest; `null` or a missing file: ingest only, no instances.
    pub reconstruction: Option<std::path::PathBuf>,
    /// Semantic model manifest (features per pixel, pooled into one prototype per instance);
    /// `null` or a missing file: instances are unnamed and associate by geometry alone.
    pub semantic: Option<std::path::PathBuf>,
}

impl Default for ModelsSection {
    fn default() -> Self {
        Self {
            onnxruntime: None,
            provider: crate::model::Provider::Cpu,
            threads: DEFAULT_MODEL_THREADS,
            text_encoder: DEFAULT_TEXT_ENCODER.into(),
            reconstruction: Some(DEFAULT_RECONSTRUCTION.into()),
            semantic: Some(DEFAULT_SEMANTIC.into()),
        }
    }
}

impl ModelsSection {
    pub fn session_options(&self) -> crate::model::SessionOptions {
        crate::model::SessionOptions {
            provider: self.provider,
            intra_threads: self.threads,
        }
    }
}

impl Config {
    /// Read and validate a YAML config file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_yaml(&text).map_err(|e| match e {
            ConfigError::Parse { source, .. } => ConfigError::Parse {
                path: path.display().to_string(),
                source,
            },
            other => other,
        })
    }

    pub fn from_yaml(text: &str) -> Result<Self> {
        let config: Self = serde_yaml_ng::from_str(text).map_err(|source| ConfigError::Parse {
            path: "<string>".into(),
            source,
        })?;
        config.validate()?;
        Ok(config)
    }

    pub fn validate(&self) -> Result<()> {
        let invalid = |msg: String| Err(ConfigError::Invalid(msg));
        use groupforward_msgs::rmw_zenoh::{resolve_name, validate_fqn};
        if let Err(e) = validate_fqn(&self.node.namespace) {
            return invalid(format!("node.namespace: {e}"));
        }
        if let Err(e) = resolve_name(&self.node.namespace, &self.node.name, "~/status") {
            return invalid(format!("node.name: {e}"));
        }
        let mut names = std::collections::BTreeSet::new();
        for camera in &self.cameras {
            if !names.insert(camera.name.as_str()) {
                return invalid(format!("camera name `{}` is used twice", camera.name));
            }
            let topics = [Some(&camera.image_topic), Some(&camera.camera_info_topic)]
                .into_iter()
                .chain([camera.depth_topic.as_ref()]);
            for topic in topics.flatten() {
                if let Err(e) = resolve_name(&self.node.namespace, &self.node.name, topic) {
                    return invalid(format!("camera `{}`: {e}", camera.name));
                }
            }
        }
        for (what, value) in [
            (
                "ingest.sync_tolerance_secs",
                self.ingest.sync_tolerance_secs,
            ),
            ("ingest.max_pose_wait_secs", self.ingest.max_pose_wait_secs),
            ("status.period_secs", self.status.period_secs),
            ("tf.history_secs", self.tf.history_secs),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return invalid(format!("{what} must be a positive number, got {value}"));
            }
        }
        if self.ingest.queue_depth == 0 || self.ingest.pending_frames == 0 {
            return invalid(
                "ingest.queue_depth and ingest.pending_frames must be at least 1".into(),
            );
        }
        if self.models.threads == 0 {
            return invalid("models.threads must be at least 1".into());
        }
        let t = self.semantics.temperature;
        if !(t.is_finite() && t > 0.0) {
            return invalid(format!(
                "semantics.temperature must be a positive number, got {t}"
            ));
        }
        if self
            .semantics
            .vocabulary
            .iter()
            .any(|p| p.trim().is_empty())
        {
            return invalid("semantics.vocabulary must not contain empty phrases".into());
        }
        if self.tf.world_frame.is_empty() {
            return invalid("tf.world_frame must not be empty".into());
        }
        Ok(())
    }

    /// The JSON API prefix: `groupforward/<namespace without slashes, or "default">`.
    pub fn api_prefix(&self) -> String {
        let ns = self.node.namespace.trim_matches('/');
        let ns = if ns.is_empty() { "default" } else { ns };
        format!("groupforward/{ns}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate() {
        Config::default().validate().unwrap();
        assert_eq!(Config::default().api_prefix(), "groupforward/default");
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let err = Config::from_yaml("node:\n  nmae: x\n").unwrap_err();
        assert!(err.to_string().contains("nmae"), "{err}");
    }

    #[test]
    fn bad_values_are_rejected() {
        assert!(Config::from_yaml("node:\n  namespace: relative\n").is_err());
        assert!(Config::from_yaml("ingest:\n  sync_tolerance_secs: -1\n").is_err());
        assert!(Config::from_yaml("status:\n  period_secs: .nan\n").is_err());
        let twice = "cameras:\n  - name: a\n  - name: a\n";
        assert!(Config::from_yaml(twice).is_err());
    }

    #[test]
    fn namespace_names_the_api() {
        let c = Config::from_yaml("node:\n  namespace: /robot1\n").unwrap();
        assert_eq!(c.api_prefix(), "groupforward/robot1");
    }
}
