//! What the node publishes about its map: each encoder is a pure function from one snapshot of the
//! map (the referring snapshot, so topics and answers describe the same map) to a message, and
//! [`OutputsSection`] names the topics and their rates.
//!
//! All in the map frame (REP 105), stamped with the newest keyframe of the snapshot:
//! - `~/instances`: `vision_msgs/Detection3DArray`, one detection per listed instance;
//! - `~/instance_array`: `groupforward_msgs/InstanceArray` (confidence, Gaussian count, seen);
//! - `~/instance_cloud`: `sensor_msgs/PointCloud2` (x, y, z, rgb, instance_id): the 3D mask;
//! - `~/instance_masks`: `groupforward_msgs/InstanceMasks` per keyframe of the last window
//!   (mono16 label image, 0 = no instance, k = `instance_ids[k-1]`; at the sensor's resolution,
//!   cut by the depth it measured, where the node kept that view's depth; else the model's);
//! - `~/markers`: `visualization_msgs/MarkerArray`, a box and a label per instance, deleted
//!   when the instance leaves the list;
//! - `~/scene_graph`: `groupforward_msgs/SceneGraph`, and the same as JSON on the JSON API.

use std::borrow::Cow;
use std::collections::HashMap;

use groupforward_msgs::builtin_interfaces::{Duration, Time};
use groupforward_msgs::geometry_msgs::{Point, PoseWithCovariance, Vector3};
use groupforward_msgs::gf_msgs::{
    EdgeView, Instance, InstanceArray, InstanceMasks, NodeView, SceneGraph, SceneGraphEdge,
    SceneGraphNode,
};
use groupforward_msgs::sensor_msgs::PointCloud2;
use groupforward_msgs::std_msgs::{ColorRGBA, Header};
use groupforward_msgs::vision_msgs::{
    BoundingBox3D, Detection3D, Detection3DArray, ObjectHypothesisWithPose,
};
use groupforward_msgs::visualization_msgs::{Marker, MarkerArray};
use serde::{Deserialize, Serialize};

use crate::frame::Keyframe;
use crate::recon::gaussians::Gaussians;
use crate::refer::response::{instance_cloud, mono16, numeric_id};
use crate::refer::scene::ReferScene;

pub const DEFAULT_OUTPUT_RATE_HZ: f64 = 2.0;
pub const DEFAULT_REPUBLISH_SECS: f64 = 5.0;
pub const DEFAULT_CLOUD_MAX_POINTS: usize = 300_000;

/// Topics the node publishes about its map. An empty topic name switches that output off.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputsSection {
    /// After the map changed, publish at most this often (Hz).
    pub max_rate_hz: f64,
    /// Publish the last messages again this often, so that a subscriber that joins late (RViz
    /// opened after the robot mapped the room) sees the map without waiting for a change
    /// (seconds; 0 = only on change).
    pub republish_secs: f64,
    pub instances: String,
    pub instance_array: String,
    pub instance_cloud: String,
    pub instance_masks: String,
    pub markers: String,
    pub scene_graph: String,
    /// The instance cloud keeps at most this many points (an even stride over the instances).
    pub cloud_max_points: usize,
}

impl Default for OutputsSection {
    fn default() -> Self {
        Self {
            max_rate_hz: DEFAULT_OUTPUT_RATE_HZ,
            republish_secs: DEFAULT_REPUBLISH_SECS,
            instances: "~/instances".into(),
            instance_array: "~/instance_array".into(),
            instance_cloud: "~/instance_cloud".into(),
            instance_masks: "~/instance_masks".into(),
            markers: "~/markers".into(),
            scene_graph: "~/scene_graph".into(),
            cloud_max_points: DEFAULT_CLOUD_MAX_POINTS,
        }
    }
}

impl OutputsSection {
    /// (key, topic) of every output, for validation and declaration.
    pub fn topics(&self) -> [(&'static str, &str); 6] {
        [
            ("instances", &self.instances),
            ("instance_array", &self.instance_array),
            ("instance_cloud", &self.instance_cloud),
            ("instance_masks", &self.instance_masks),
            ("markers", &self.markers),
            ("scene_graph", &self.scene_graph),
        ]
    }
}

/// A camera's name and optical frame for a keyframe (by stamp): a keyframe keeps neither.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ViewSource {
    pub stamp_nanos: i64,
    pub camera: String,
    pub frame_id: String,
}

/// The header every map message carries: the map frame, the snapshot's newest keyframe.
pub fn map_header(scene: &ReferScene, world_frame: &str) -> Header {
    Header {
        stamp: scene
            .keyframes
            .first()
            .map_or(Time::default(), |k| Time::from_nanos(k.stamp_nanos)),
        frame_id: world_frame.to_owned(),
    }
}

/// `vision_msgs/Detection3DArray` (Jazzy): per instance its persistent id, its class hypotheses
/// each with the instance's pose, and its gravity-aligned box.
pub fn detections(header: &Header, instances: &[Instance]) -> Detection3DArray {
    Detection3DArray {
        header: header.clone(),
        detections: instances
            .iter()
            .map(|i| Detection3D {
                header: header.clone(),
                results: i
                    .hypotheses
                    .iter()
                    .map(|h| ObjectHypothesisWithPose {
                        hypothesis: h.clone(),
                        pose: PoseWithCovariance {
                            pose: i.pose,
                            ..Default::default()
                        },
                    })
                    .collect(),
                bbox: BoundingBox3D {
                    center: i.pose,
                    size: i.size,
                },
                id: i.id.clone(),
            })
            .collect(),
    }
}

pub fn instance_array(header: &Header, instances: &[Instance]) -> InstanceArray {
    InstanceArray {
        header: header.clone(),
        instances: instances.to_vec(),
    }
}

/// The listed instances the snapshot's map holds, with their Gaussians, in the list's order.
fn listed_gaussians<'a, 'b>(
    scene: &'a ReferScene,
    instances: &'b [Instance],
) -> Vec<(&'b Instance, &'a Gaussians)> {
    let by_id: HashMap<&str, &Gaussians> = scene
        .map
        .instances
        .iter()
        .map(|i| (i.id.as_str(), &i.gaussians))
        .collect();
    instances
        .iter()
        .filter_map(|i| by_id.get(i.id.as_str()).map(|g| (i, *g)))
        .collect()
}

/// The 3D instance mask: every listed instance's Gaussians with its numeric id (structure and
/// noise are not listed, so not in it), thinned by an even stride to at most `max_points`.
pub fn cloud(
    header: &Header,
    scene: &ReferScene,
    instances: &[Instance],
    max_points: usize,
) -> PointCloud2 {
    let listed = listed_gaussians(scene, instances);
    let total: usize = listed.iter().map(|(_, g)| g.len()).sum();
    let stride = total.div_ceil(max_points.max(1)).max(1);
    // Within the budget the Gaussians are borrowed as they are; over it, every stride-th.
    let thinned: Vec<(u32, Cow<Gaussians>)> = listed
        .into_iter()
        .map(|(i, g)| {
            let g = match stride {
                1 => Cow::Borrowed(g),
                _ => Cow::Owned(g.select((0..g.len()).step_by(stride))),
            };
            (numeric_id(&i.id), g)
        })
        .collect();
    let items: Vec<(u32, &Gaussians)> = thinned.iter().map(|(id, g)| (*id, g.as_ref())).collect();
    let mut message = instance_cloud(&header.frame_id, header.stamp, &items);
    message.header = header.clone();
    message
}

/// Per keyframe of the snapshot (the last window's views, newest first), the label image of the
/// listed instances, 0 where none is (structure included). Where the snapshot kept the sensor's
/// depth for the keyframe, at the sensor's resolution: a pixel is the listed instance whose map
/// points its reading lies on ([`crate::refer::masks::measured_labels`]; 0 where it read
/// nothing). Otherwise at the model's resolution: the snapshot's whole-map render (nearest surface
/// wins, so what structure or other instances hide stays out). `sources` name each keyframe's
/// camera and optical frame (by stamp); a keyframe without one has empty names.
pub fn masks(
    scene: &ReferScene,
    instances: &[Instance],
    sources: &[ViewSource],
) -> Vec<InstanceMasks> {
    let ids: Vec<String> = instances.iter().map(|i| i.id.clone()).collect();
    let listed = ListedLabels::new(scene, instances);
    scene
        .keyframes
        .iter()
        .enumerate()
        .map(|(k, keyframe)| {
            let source = sources
                .iter()
                .find(|s| s.stamp_nanos == keyframe.stamp_nanos)
                .cloned()
                .unwrap_or_default();
            let header = Header {
                stamp: Time::from_nanos(keyframe.stamp_nanos),
                frame_id: source.frame_id,
            };
            let (view, labels) = listed.in_keyframe(scene, k, keyframe);
            InstanceMasks {
                header: header.clone(),
                camera: source.camera,
                mask: mono16(header, view.camera.width, view.camera.height, &labels),
                instance_ids: ids.clone(),
            }
        })
        .collect()
}

/// The listed instances as the snapshot's map holds them, each with its label (1 + its place in
/// the list), and the map's points around them for masks cut by measured depth.
struct ListedLabels {
    /// Per map instance, its label (0: not listed).
    label_of_map: Vec<u16>,
    /// The labels of the listed instances the map holds, in the map's order.
    labels: Vec<u16>,
    volume: Option<crate::refer::masks::AnswerVolume>,
}

impl ListedLabels {
    fn new(scene: &ReferScene, instances: &[Instance]) -> Self {
        let position: HashMap<&str, u16> = instances
            .iter()
            .enumerate()
            .map(|(k, i)| (i.id.as_str(), (k + 1).min(usize::from(u16::MAX)) as u16))
            .collect();
        let label_of_map: Vec<u16> = scene
            .map
            .instances
            .iter()
            .map(|i| position.get(i.id.as_str()).copied().unwrap_or(0))
            .collect();
        let chosen: Vec<usize> = (0..label_of_map.len())
            .filter(|&m| label_of_map[m] > 0)
            .collect();
        let volume = crate::refer::masks::measured_volume(scene, &chosen);
        Self {
            labels: chosen.iter().map(|&m| label_of_map[m]).collect(),
            label_of_map,
            volume,
        }
    }

    /// The view the `k`-th keyframe's labels are at, and the labels.
    fn in_keyframe<'a>(
        &self,
        scene: &'a ReferScene,
        k: usize,
        keyframe: &'a Keyframe,
    ) -> (&'a Keyframe, Vec<u16>) {
        let measured = scene.measured.get(k).and_then(Option::as_ref);
        if let (Some(m), Some(volume)) = (measured, self.volume.as_ref()) {
            // Where the sensor read nothing the pixel is 0: the splats an answer falls back to
            // there would be drawn over every listed instance, several times the cost of the
            // rest (`bench outputs`).
            let found = crate::refer::masks::measured_view_labels(volume, m);
            let labels = found
                .iter()
                .map(|&f| match f {
                    None | Some(0) => 0,
                    Some(f) => self.labels.get(usize::from(f) - 1).copied().unwrap_or(0),
                })
                .collect();
            return (&m.keyframe, labels);
        }
        let pixels = scene.labels.get(k).map_or(&[][..], Vec::as_slice);
        let labels = pixels
            .iter()
            .map(|p| {
                p.and_then(|m| self.label_of_map.get(m as usize).copied())
                    .unwrap_or(0)
            })
            .collect();
        (keyframe, labels)
    }
}

/// Marker namespaces: one box and one label per instance, both with the instance's numeric id,
/// and one line list (id 0) of the scene graph's edges.
pub const BOX_NAMESPACE: &str = "instances";
pub const LABEL_NAMESPACE: &str = "labels";
pub const EDGE_NAMESPACE: &str = "edges";

/// A colour per id, the same on every message (a golden-angle hue walk: neighbours differ).
fn id_color(id: u32, alpha: f32) -> ColorRGBA {
    let hue = (id as f32 * 0.618_034).fract() * 6.0;
    let x = 1.0 - (hue % 2.0 - 1.0).abs();
    let (r, g, b) = match hue as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    ColorRGBA { r, g, b, a: alpha }
}

/// RViz / Foxglove markers: a translucent box and a text label ("inst_000003 chair 0.79") per
/// instance, a DELETE for both of every id in `gone` (listed before, not now), and the scene
/// graph's edges as one line list between node centres (deleted when there are none).
pub fn markers(
    header: &Header,
    instances: &[Instance],
    gone: &[String],
    graph: &SceneGraph,
) -> MarkerArray {
    let mut markers = Vec::with_capacity(2 * instances.len() + 2 * gone.len());
    for i in instances {
        let id = numeric_id(&i.id) as i32;
        markers.push(Marker {
            header: header.clone(),
            ns: BOX_NAMESPACE.into(),
            id,
            marker_type: Marker::CUBE,
            action: Marker::ADD,
            pose: i.pose,
            scale: Vector3 {
                x: i.size.x.max(0.01),
                y: i.size.y.max(0.01),
                z: i.size.z.max(0.01),
            },
            color: id_color(id as u32, 0.4),
            lifetime: Duration::default(),
            ..Default::default()
        });
        let mut label_pose = i.pose;
        label_pose.position.z += i.size.z / 2.0 + 0.1;
        let name = i.hypotheses.first().map_or("", |h| h.class_id.as_str());
        let score = i.hypotheses.first().map_or(0.0, |h| h.score);
        markers.push(Marker {
            header: header.clone(),
            ns: LABEL_NAMESPACE.into(),
            id,
            marker_type: Marker::TEXT_VIEW_FACING,
            action: Marker::ADD,
            pose: label_pose,
            scale: Vector3 {
                z: 0.12,
                ..Default::default()
            },
            color: ColorRGBA {
                r: 1.0,
                g: 1.0,
                b: 1.0,
                a: 1.0,
            },
            text: format!("{} {name} {score:.2}", i.id),
            ..Default::default()
        });
    }
    let centre: HashMap<&str, Point> = graph
        .nodes
        .iter()
        .map(|n| (n.id.as_str(), n.center))
        .collect();
    let points: Vec<Point> = graph
        .edges
        .iter()
        .filter_map(|e| {
            Some([
                *centre.get(e.source.as_str())?,
                *centre.get(e.target.as_str())?,
            ])
        })
        .flatten()
        .collect();
    markers.push(Marker {
        header: header.clone(),
        ns: EDGE_NAMESPACE.into(),
        id: 0,
        marker_type: Marker::LINE_LIST,
        action: if points.is_empty() {
            Marker::DELETE
        } else {
            Marker::ADD
        },
        scale: Vector3 {
            x: 0.01,
            ..Default::default()
        },
        color: ColorRGBA {
            r: 0.7,
            g: 0.7,
            b: 0.7,
            a: 0.6,
        },
        points,
        ..Default::default()
    });
    for id in gone {
        for ns in [BOX_NAMESPACE, LABEL_NAMESPACE] {
            markers.push(Marker {
                header: header.clone(),
                ns: ns.into(),
                id: numeric_id(id) as i32,
                action: Marker::DELETE,
                ..Default::default()
            });
        }
    }
    MarkerArray { markers }
}

/// `groupforward_msgs/SceneGraph` over the listed instances: each node's box from its instance
/// message (the same box as `~/instances`), its prototype, and per keyframe of the snapshot
/// (newest first) its projected box and visibility; edges between listed instances.
pub fn scene_graph(header: &Header, scene: &ReferScene, instances: &[Instance]) -> SceneGraph {
    let graph = &scene.graph;
    let keyframe_ids: Vec<String> = graph
        .keyframe_stamps
        .iter()
        .map(|s| s.to_string())
        .collect();
    let listed: HashMap<&str, &Instance> = instances.iter().map(|i| (i.id.as_str(), i)).collect();
    // Graph node index -> published node index.
    let mut index = HashMap::new();
    let mut nodes = Vec::new();
    for (k, node) in graph.nodes.iter().enumerate() {
        let Some(instance) = listed.get(node.id.as_str()) else {
            continue;
        };
        index.insert(k, nodes.len());
        let size = instance.size;
        nodes.push(SceneGraphNode {
            id: node.id.clone(),
            label: instance
                .hypotheses
                .first()
                .map_or(String::new(), |h| h.class_id.clone()),
            prototype: node.prototype.clone(),
            center: instance.pose.position,
            extent: size,
            volume: size.x * size.y * size.z,
            views: node
                .views
                .iter()
                .zip(&keyframe_ids)
                .map(|(v, keyframe_id)| {
                    let [x_min, y_min, x_max, y_max] = v.bbox.unwrap_or([0.0; 4]);
                    NodeView {
                        keyframe_id: keyframe_id.clone(),
                        x_min,
                        y_min,
                        x_max,
                        y_max,
                        visibility: v.visibility,
                    }
                })
                .collect(),
        });
    }
    let edges = graph
        .edges
        .iter()
        .filter_map(|e| {
            let (a, b) = (*index.get(&e.source)?, *index.get(&e.target)?);
            let (ca, cb) = (nodes[a].center, nodes[b].center);
            let (va, vb) = (nodes[a].volume, nodes[b].volume);
            Some(SceneGraphEdge {
                source: nodes[a].id.clone(),
                target: nodes[b].id.clone(),
                distance: ((ca.x - cb.x).powi(2) + (ca.y - cb.y).powi(2) + (ca.z - cb.z).powi(2))
                    .sqrt(),
                height_difference: ca.z - cb.z,
                size_ratio: va.max(1e-9) / vb.max(1e-9),
                views: e
                    .views
                    .iter()
                    .zip(&keyframe_ids)
                    .map(|(v, keyframe_id)| EdgeView {
                        keyframe_id: keyframe_id.clone(),
                        // -1: the pair is not both in that view.
                        projected_distance: v.distance.unwrap_or(-1.0),
                        direction: v.direction.unwrap_or(0.0),
                        overlap: v.overlap.unwrap_or(0.0),
                    })
                    .collect(),
            })
        })
        .collect();
    SceneGraph {
        header: header.clone(),
        nodes,
        edges,
    }
}

/// The scene graph as JSON for clients without ROS (prototypes left out: they are model
/// internals; the ROS message carries them).
pub fn scene_graph_json(graph: &SceneGraph) -> serde_json::Value {
    let point = |p: &Point| serde_json::json!([p.x, p.y, p.z]);
    serde_json::json!({
        "frame_id": graph.header.frame_id,
        "stamp_nanos": graph.header.stamp.as_nanos(),
        "nodes": graph.nodes.iter().map(|n| serde_json::json!({
            "id": n.id,
            "label": n.label,
            "center": point(&n.center),
            "extent": [n.extent.x, n.extent.y, n.extent.z],
            "volume": n.volume,
            "views": n.views.iter().map(|v| serde_json::json!({
                "keyframe": v.keyframe_id,
                "box": [v.x_min, v.y_min, v.x_max, v.y_max],
                "visibility": v.visibility,
            })).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "edges": graph.edges.iter().map(|e| serde_json::json!({
            "source": e.source,
            "target": e.target,
            "distance": e.distance,
            "height_difference": e.height_difference,
            "size_ratio": e.size_ratio,
        })).collect::<Vec<_>>(),
    })
}

#[cfg(test)]
mod tests {
    use groupforward_msgs::vision_msgs::ObjectHypothesis;

    use super::*;
    use crate::frame::WindowInstance;
    use crate::graph::{FusionParams, SceneMap};
    use crate::node::instance_messages;
    use crate::recon::camera::Camera;
    use crate::recon::Rigid;
    use crate::refer::masks::tests::wall;

    /// A map of the given walls (one instance each, ids inst_000001...) and two keyframes at
    /// the origin looking along +z (stamps 5 and 6).
    fn map_of(walls: Vec<Gaussians>) -> SceneMap {
        let mut map = SceneMap::new(FusionParams::default());
        for (k, gaussians) in walls.into_iter().enumerate() {
            map.fuse(
                vec![WindowInstance {
                    gaussians,
                    prototype: vec![1.0, k as f32],
                    support: 10,
                }],
                &[],
                k as i64,
            )
            .unwrap();
        }
        for stamp in [5, 6] {
            map.keyframes.push_back(Keyframe {
                stamp_nanos: stamp,
                camera: Camera::from_fov(64, 48, 1.2).unwrap(),
                world_from_camera: Rigid::default(),
            });
        }
        map
    }

    fn scene_of(map: SceneMap) -> (ReferScene, Vec<Instance>) {
        let instances = instance_messages(&map, None, 3);
        (ReferScene::build(map, None).unwrap(), instances)
    }

    #[test]
    fn masks_name_their_camera_and_label_each_instance_by_its_place_in_instance_ids() {
        let (scene, instances) =
            scene_of(map_of(vec![wall(-0.6, -0.02, 2.0), wall(0.02, 0.6, 2.0)]));
        // Listed in the other order: labels follow the list, not the map.
        let listed = vec![instances[1].clone(), instances[0].clone()];
        let sources = [ViewSource {
            stamp_nanos: 6,
            camera: "front".into(),
            frame_id: "front_optical".into(),
        }];
        let masks = masks(&scene, &listed, &sources);
        assert_eq!(masks.len(), 2, "one per keyframe of the snapshot");
        let newest = &masks[0];
        assert_eq!(newest.header.stamp.as_nanos(), 6);
        assert_eq!(
            (newest.camera.as_str(), newest.header.frame_id.as_str()),
            ("front", "front_optical")
        );
        assert_eq!(newest.instance_ids, ["inst_000002", "inst_000001"]);
        assert_eq!(
            (
                newest.mask.encoding.as_str(),
                newest.mask.width,
                newest.mask.height
            ),
            ("mono16", 64, 48)
        );
        let label = |col: usize| {
            let o = (24 * 64 + col) * 2;
            u16::from_le_bytes([newest.mask.data[o], newest.mask.data[o + 1]])
        };
        // Left of centre is the first wall (inst_000001, listed second), right the other.
        assert_eq!(label(20), 2);
        assert_eq!(label(44), 1);
        // A keyframe no source names is still published, without names.
        assert_eq!(masks[1].camera, "");
        // An instance not listed (structure) is no label: its pixels are 0.
        let only_first = super::masks(&scene, &instances[..1], &sources);
        let at = |col: usize| {
            let o = (24 * 64 + col) * 2;
            u16::from_le_bytes([only_first[0].mask.data[o], only_first[0].mask.data[o + 1]])
        };
        assert_eq!((at(20), at(44)), (1, 0));
    }

    #[test]
    fn the_cloud_keeps_to_its_point_budget_across_every_instance() {
        let (scene, instances) =
            scene_of(map_of(vec![wall(-0.6, -0.02, 2.0), wall(0.02, 0.6, 2.0)]));
        let header = map_header(&scene, "map");
        let total: usize = scene.map.instances.iter().map(|i| i.gaussians.len()).sum();
        let full = cloud(&header, &scene, &instances, usize::MAX);
        assert_eq!(full.width as usize, total);
        let thin = cloud(&header, &scene, &instances, 50);
        assert!(thin.width > 0 && thin.width <= 50, "{}", thin.width);
        let ids: std::collections::BTreeSet<u32> = thin
            .data
            .chunks_exact(thin.point_step as usize)
            .map(|p| u32::from_le_bytes(p[16..20].try_into().unwrap()))
            .collect();
        assert_eq!(ids.into_iter().collect::<Vec<_>>(), [1, 2]);
        assert_eq!(thin.header.frame_id, "map");
        // Nothing listed: an empty cloud, not an error.
        assert_eq!(cloud(&header, &scene, &[], 50).width, 0);
    }

    #[test]
    fn the_graph_keeps_listed_instances_only_and_joins_them_by_id() {
        let (scene, instances) = scene_of(map_of(vec![
            wall(-0.6, -0.3, 2.0),
            wall(-0.1, 0.1, 2.0),
            wall(0.3, 0.6, 2.0),
        ]));
        // The middle one is not listed (as structure is not).
        let listed = vec![instances[0].clone(), instances[2].clone()];
        let header = map_header(&scene, "map");
        let graph = scene_graph(&header, &scene, &listed);
        let ids: Vec<&str> = graph.nodes.iter().map(|n| n.id.as_str()).collect();
        assert_eq!(ids, ["inst_000001", "inst_000003"]);
        assert_eq!(graph.edges.len(), 1);
        let edge = &graph.edges[0];
        assert_eq!(
            (edge.source.as_str(), edge.target.as_str()),
            ("inst_000001", "inst_000003")
        );
        // Node boxes are the instance messages' boxes; the edge distance joins their centres.
        assert_eq!(graph.nodes[0].center, listed[0].pose.position);
        let (a, b) = (listed[0].pose.position, listed[1].pose.position);
        assert!((edge.distance - ((a.x - b.x).powi(2) + (a.y - b.y).powi(2)).sqrt()).abs() < 1e-6);
        assert_eq!(edge.views.len(), 2);
        assert!(graph.nodes.iter().all(|n| n.views.len() == 2));
        let json = scene_graph_json(&graph);
        assert_eq!(json["edges"][0]["target"], "inst_000003");
        // The edge is drawn as one line between the two centres.
        let lines = markers(&header, &listed, &[], &graph);
        let edges = lines.markers.last().unwrap();
        assert_eq!(
            (edges.ns.as_str(), edges.action),
            (EDGE_NAMESPACE, Marker::ADD)
        );
        assert_eq!(edges.points, [a, b]);
        assert_eq!(json["nodes"].as_array().unwrap().len(), 2);
    }

    #[test]
    fn markers_add_a_box_and_a_label_per_instance_and_delete_those_that_left() {
        let mut instance = Instance {
            id: "inst_000004".into(),
            hypotheses: vec![ObjectHypothesis {
                class_id: "chair".into(),
                score: 0.8,
            }],
            ..Default::default()
        };
        instance.size = Vector3 {
            x: 0.5,
            y: 0.4,
            z: 0.0,
        };
        let header = Header::default();
        let m = markers(
            &header,
            &[instance],
            &["inst_000009".into()],
            &SceneGraph::default(),
        );
        let summary: Vec<(&str, i32, i32, i32)> = m
            .markers
            .iter()
            .map(|m| (m.ns.as_str(), m.id, m.marker_type, m.action))
            .collect();
        assert_eq!(
            summary,
            [
                (BOX_NAMESPACE, 4, Marker::CUBE, Marker::ADD),
                (LABEL_NAMESPACE, 4, Marker::TEXT_VIEW_FACING, Marker::ADD),
                (EDGE_NAMESPACE, 0, Marker::LINE_LIST, Marker::DELETE),
                (BOX_NAMESPACE, 9, 0, Marker::DELETE),
                (LABEL_NAMESPACE, 9, 0, Marker::DELETE),
            ]
        );
        // A flat box is still drawable; the label names id, class and score.
        assert!(m.markers[0].scale.z > 0.0);
        assert_eq!(m.markers[1].text, "inst_000004 chair 0.80");
        // Colours belong to ids: the same on every message, different for neighbours.
        assert_eq!(id_color(4, 0.4), id_color(4, 0.4));
        assert_ne!(id_color(4, 0.4), id_color(5, 0.4));
    }

    #[test]
    fn detections_carry_the_persistent_id_every_hypothesis_and_the_box() {
        let (scene, mut instances) = scene_of(map_of(vec![wall(-0.2, 0.2, 2.0)]));
        instances[0].hypotheses = vec![
            ObjectHypothesis {
                class_id: "table".into(),
                score: 0.6,
            },
            ObjectHypothesis {
                class_id: "desk".into(),
                score: 0.3,
            },
        ];
        let header = map_header(&scene, "map");
        assert_eq!(header.stamp.as_nanos(), 6, "the newest keyframe");
        let d = detections(&header, &instances);
        let detection = &d.detections[0];
        assert_eq!(detection.id, "inst_000001");
        assert_eq!(detection.results.len(), 2);
        assert_eq!(detection.results[1].hypothesis.class_id, "desk");
        assert_eq!(detection.results[0].pose.pose, instances[0].pose);
        assert_eq!(detection.bbox.center, instances[0].pose);
        assert_eq!(detection.bbox.size, instances[0].size);
        assert_eq!(instance_array(&header, &instances).instances, instances);
    }

    /// Each mask's stamp and size, and the label at column `x` of the middle row of the first.
    fn stamps_sizes_and_middle_row(
        masks: &[InstanceMasks],
    ) -> (Vec<(i64, u32, u32)>, impl Fn(usize) -> u16 + '_) {
        let sizes = masks
            .iter()
            .map(|m| (m.header.stamp.as_nanos(), m.mask.width, m.mask.height))
            .collect();
        let first = &masks[0].mask;
        let label = move |x: usize| {
            let o = 2 * ((first.height as usize / 2) * first.width as usize + x);
            u16::from_le_bytes([first.data[o], first.data[o + 1]])
        };
        (sizes, label)
    }

    #[test]
    fn published_masks_are_at_the_sensor_s_resolution_where_the_snapshot_kept_its_depth() {
        use crate::frame::MeasuredDepth;
        let (scene, instances) =
            scene_of(map_of(vec![wall(-0.6, -0.02, 2.0), wall(0.02, 0.6, 2.0)]));
        // The newest keyframe's sensor measured both walls at 2 m, at twice the model's size,
        // and the wall beyond them (3 m) on the left of the picture.
        let sensor = Keyframe {
            stamp_nanos: 6,
            camera: Camera::from_fov(128, 96, 1.2).unwrap(),
            world_from_camera: Rigid::default(),
        };
        // One pixel of the right wall without a reading.
        let depth = (0..128 * 96)
            .map(|p| match p {
                p if p == 48 * 128 + 100 => f32::NAN,
                p if p % 128 < 8 => 3.0,
                _ => 2.0,
            })
            .collect();
        let measured = std::sync::Arc::new(MeasuredDepth::new(sensor, depth, Some(0.001)));
        let scene = scene.with_measured(&[measured]);
        // Listed in the other order: labels follow the list.
        let listed = vec![instances[1].clone(), instances[0].clone()];
        let masks = masks(&scene, &listed, &[]);
        let (sizes, label) = stamps_sizes_and_middle_row(&masks);
        assert_eq!(
            sizes,
            vec![(6, 128, 96), (5, 64, 48)],
            "measured, then the render"
        );
        // Left wall (listed second), right wall (listed first), the far wall nobody listed, and
        // the pixel the sensor read nothing at.
        assert_eq!((label(40), label(88), label(2), label(100)), (2, 1, 0, 0));
    }

    #[test]
    fn an_answer_s_masks_are_at_the_sensor_s_resolution_where_the_snapshot_kept_its_depth() {
        use crate::frame::MeasuredDepth;
        use crate::refer::{parse::parse, reasoner::Choice, response::response, Answer};
        let (scene, _) = scene_of(map_of(vec![wall(-0.6, -0.02, 2.0), wall(0.02, 0.6, 2.0)]));
        // The newest keyframe's sensor measured both walls at 2 m, at twice the model's size.
        let sensor = Keyframe {
            stamp_nanos: 6,
            camera: Camera::from_fov(128, 96, 1.2).unwrap(),
            world_from_camera: Rigid::default(),
        };
        let measured =
            std::sync::Arc::new(MeasuredDepth::new(sensor, vec![2.0; 128 * 96], Some(0.001)));
        let scene = scene.with_measured(&[measured]);
        let right = scene
            .nodes
            .iter()
            .position(|n| n.id == "inst_000002")
            .unwrap();
        let answer = Answer {
            query: parse("the wall").unwrap(),
            chosen: vec![Choice {
                index: right,
                confidence: 1.0,
            }],
            note: None,
            candidates: Vec::new(),
            reasoner_used: "builtin".into(),
            trace: String::new(),
            view: None,
        };
        let gaussians = vec![scene.gaussians("inst_000002")];
        let reply = response(&answer, &scene, &gaussians, "map", None);
        let (sizes, labelled) = stamps_sizes_and_middle_row(&reply.view_masks);
        assert_eq!(
            sizes,
            vec![(6, 128, 96), (5, 64, 48)],
            "measured, then splats"
        );
        assert_eq!(
            (labelled(40), labelled(88)),
            (0, 1),
            "the right wall, not the left"
        );
    }
}
