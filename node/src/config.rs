//! Node configuration: one YAML file (`launch/groupforward.yaml` is the commented default), parsed
//! into serde structs that reject unknown keys, with every default a named constant.
//!
//! Each stage owns its section (ingest: cameras, TF, sync; model; window; graph: map; group:
//! semantics; transport: zenoh); this module only assembles them, adds the node's own sections
//! (name, status) and checks what spans sections.

use crate::outputs::OutputsSection;
use crate::refer::ReferSection;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::graph::persist::MapSection;
use crate::group::semantics::SemanticsSection;
use crate::ingest::{CameraConfig, IngestSection, TfSection};
use crate::model::ModelsSection;
use crate::transport::{TransportKind, ZenohSection};
use crate::window::WindowSection;

pub const DEFAULT_NODE_NAME: &str = "groupforward";
pub const DEFAULT_NAMESPACE: &str = "/";
pub const DEFAULT_STATUS_PERIOD_SECS: f64 = 1.0;

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
    pub transport: TransportKind,
    pub zenoh: ZenohSection,
    pub cameras: Vec<CameraConfig>,
    pub tf: TfSection,
    pub ingest: IngestSection,
    pub status: StatusSection,
    pub models: ModelsSection,
    pub window: WindowSection,
    pub map: MapSection,
    pub semantics: SemanticsSection,
    pub refer: ReferSection,
    pub outputs: OutputsSection,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            node: NodeSection::default(),
            transport: TransportKind::default(),
            zenoh: ZenohSection::default(),
            cameras: vec![CameraConfig::default()],
            tf: TfSection::default(),
            ingest: IngestSection::default(),
            status: StatusSection::default(),
            models: ModelsSection::default(),
            window: WindowSection::default(),
            map: MapSection::default(),
            semantics: SemanticsSection::default(),
            refer: ReferSection::default(),
            outputs: OutputsSection::default(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NodeSection {
    pub name: String,
    /// Absolute ROS namespace; also names the JSON API prefix (`groupforward/<namespace>/...`).
    pub namespace: String,
    /// Requests the services and the JSON API take per second, all together (a burst of as many
    /// is allowed); more are refused with the reason and counted in the status. 0: no bound.
    pub max_requests_per_second: f64,
}

/// Well above a navigation stack's query rate (the reliability suite's flood asks at 20 Hz),
/// well below what would starve the window pass of the map's lock.
pub const DEFAULT_MAX_REQUESTS_PER_SECOND: f64 = 100.0;

impl Default for NodeSection {
    fn default() -> Self {
        Self {
            name: DEFAULT_NODE_NAME.into(),
            namespace: DEFAULT_NAMESPACE.into(),
            max_requests_per_second: DEFAULT_MAX_REQUESTS_PER_SECOND,
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
            ("outputs.max_rate_hz", self.outputs.max_rate_hz),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return invalid(format!("{what} must be a positive number, got {value}"));
            }
        }
        let rate = self.node.max_requests_per_second;
        if !(rate.is_finite() && rate >= 0.0) {
            return invalid(format!(
                "node.max_requests_per_second must be 0 (no bound) or a positive number, got {rate}"
            ));
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
        if let Err(e) = self.semantics.class_priors() {
            return invalid(format!("semantics.vocabulary_file: {e}"));
        }
        if self.tf.world_frame.is_empty() {
            return invalid("tf.world_frame must not be empty".into());
        }
        let republish = self.outputs.republish_secs;
        if !(republish.is_finite() && republish >= 0.0) {
            return invalid(format!(
                "outputs.republish_secs must be 0 or a positive number, got {republish}"
            ));
        }
        for (what, topic) in self.outputs.topics() {
            if topic.is_empty() {
                continue;
            }
            if let Err(e) = resolve_name(&self.node.namespace, &self.node.name, topic) {
                return invalid(format!("outputs.{what}: {e}"));
            }
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
        for rate in ["-1", ".nan", ".inf"] {
            let yaml = format!("node:\n  max_requests_per_second: {rate}\n");
            assert!(Config::from_yaml(&yaml).is_err(), "{rate}");
        }
        assert!(Config::from_yaml("node:\n  max_requests_per_second: 0\n").is_ok());
        let twice = "cameras:\n  - name: a\n  - name: a\n";
        assert!(Config::from_yaml(twice).is_err());
    }

    #[test]
    fn namespace_names_the_api() {
        let c = Config::from_yaml("node:\n  namespace: /robot1\n").unwrap();
        assert_eq!(c.api_prefix(), "groupforward/robot1");
    }
}
