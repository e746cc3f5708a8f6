//! Referring against ground truth: a scene's generated expressions asked through the `Refer`
//! service's handler (CDR request in, CDR response out, exactly what a ROS 2 client gets) on the
//! scene's final map; each answered instance is matched to the object its box overlaps most, and
//! the answer is right when those objects are exactly the expression's targets.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use groupforward_msgs::cdr;
use groupforward_msgs::geometry_msgs::{Point, Pose, Quaternion};
use groupforward_msgs::gf_msgs::{Instance, ReferRequest, ReferResponse};
use groupforward_msgs::vision_msgs::BoundingBox3D;
use groupforward_sim::referring::Expression;
use serde::Serialize;

use super::score::TruthObject;
use groupforward::frame::{Keyframe, MeasuredDepth};
use groupforward::graph::SceneMap;
use groupforward::group::semantics::Vocabulary;
use groupforward::model::text::TextEncoder;
use groupforward::node::services::{handle_refer, Shared};
use groupforward::recon::boxes::OrientedBox;
use groupforward::recon::camera::Camera;
use groupforward::recon::depth_noise::noise_at_1m;
use groupforward::recon::gaussians::Gaussians;
use groupforward::recon::raster::{render, RasterSettings};
use groupforward::recon::Rigid;
use groupforward::refer::masks::{answer_labels, measured_view_labels, AnswerVolume};
use groupforward::refer::response::pose_box;
use groupforward::refer::ReferSection;
use groupforward_sim::simulation::Simulation;

/// An answer box farther than this from every object (and overlapping none) names no object.
const MATCH_DISTANCE_M: f64 = 0.5;

/// Every this many frames of the trajectory, offset by half of it from the first frame.
pub const HELD_OUT_EVERY: usize = 10;

/// A view of the scene for scoring masks, at the sensor's resolution: a camera pose and
/// intrinsics, the ground-truth instance ids seen there, the depth the sensor measured there
/// (`None`: the node was run without depth) with its range noise, and the map's depth rendered
/// there (the splats' occlusion cut).
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOutView {
    pub keyframe: Keyframe,
    pub truth: Vec<u16>,
    pub measured: Option<MeasuredDepth>,
    pub scene_depth: Vec<f32>,
}

/// Views of `sim`'s first camera every [`HELD_OUT_EVERY`] frames starting half a stride in,
/// (pinhole cameras only), with `map`'s depth rendered there and, `with_depth`, the sensor's.
pub fn held_out_views(sim: &Simulation, map: &SceneMap, with_depth: bool) -> Vec<HeldOutView> {
    let mut all = Gaussians::with_dims(0, 0);
    for instance in &map.instances {
        all.extend_geometry(&instance.gaussians);
    }
    (HELD_OUT_EVERY / 2..sim.frame_count())
        .step_by(HELD_OUT_EVERY)
        .filter_map(|i| {
            let frame = sim.frame(i);
            let view = frame.views.into_iter().find(|v| v.camera == 0)?;
            if view.distortion.is_some() {
                return None;
            }
            let p = view.pinhole;
            let camera = Camera::pinhole(p.width, p.height, p.fx, p.fy, p.cx, p.cy).ok()?;
            let keyframe = Keyframe {
                stamp_nanos: (frame.stamp_secs * 1e9) as i64,
                camera,
                world_from_camera: Rigid::new(view.rotation, view.position),
            };
            let scene_depth = render(
                &all,
                &[],
                0,
                &keyframe.camera,
                &keyframe.world_from_camera.inverse(),
                &RasterSettings::default(),
            )
            .map(|r| r.depth)
            .unwrap_or_default();
            let measured = with_depth.then(|| {
                let depth = view.sensor_depth().to_vec();
                let noise = noise_at_1m([(depth.as_slice(), p.width as usize)]);
                MeasuredDepth::new(keyframe.clone(), depth, noise)
            });
            Some(HeldOutView {
                keyframe,
                truth: view.truth.instance.clone(),
                measured,
                scene_depth,
            })
        })
        .collect()
}

/// Mean IoU, over the held-out views that see a target, of the answer's mask (`chosen`: indices
/// into `instances`, the whole map) against the targets' ground-truth mask (an answer without
/// instances scores 0 there). Masks are the node's: cut by the measured depth where the view has
/// it, the rendered splats elsewhere.
pub fn referring_iou(
    instances: &[&Gaussians],
    chosen: &[usize],
    targets: &[u16],
    views: &[HeldOutView],
) -> Option<f64> {
    let answer: Vec<&Gaussians> = chosen
        .iter()
        .filter_map(|&k| instances.get(k).copied())
        .collect();
    let volume = AnswerVolume::new(instances, chosen);
    let mut ious = Vec::new();
    for view in views {
        let truth: Vec<bool> = view.truth.iter().map(|id| targets.contains(id)).collect();
        if !truth.iter().any(|t| *t) {
            continue;
        }
        let predicted = answer_labels(
            &answer,
            volume.as_ref(),
            &view.keyframe,
            view.measured.as_ref(),
            &view.scene_depth,
        );
        let pairs = predicted.iter().zip(&truth).map(|(p, t)| (*p > 0, *t));
        ious.push(mask_iou(pairs).unwrap_or(0.0));
    }
    (!ious.is_empty()).then(|| ious.iter().sum::<f64>() / ious.len() as f64)
}

/// Which truth an expression is scored by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Truth {
    /// Decided over the objects the trajectory observed: right when the answer is its targets.
    Observed,
    /// Its targets were never observed: right only when the answer is a refusal that says why.
    Refusal,
    /// Decided over every object of the scene, seen or not (the benchmark before refusals).
    EveryObject,
}

impl Truth {
    pub fn name(self) -> &'static str {
        match self {
            Truth::Observed => "observed",
            Truth::Refusal => "refusal",
            Truth::EveryObject => "every_object",
        }
    }
}

/// One expression, asked and scored.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReferRecord {
    pub scene: String,
    /// The truth it was scored by.
    pub truth: Truth,
    pub expression: String,
    pub relation: String,
    pub view_dependent: bool,
    /// ReferIt3D "hard": more than 2 distractors of the target's class.
    pub hard: bool,
    /// Objects of the target's class that are not targets (ScanRefer "unique": none).
    pub distractors: usize,
    pub targets: Vec<u16>,
    /// The objects the answered instances were matched to (0: none).
    pub answered: Vec<u16>,
    pub correct: bool,
    /// Every target is among the retrieved candidates.
    pub topk_hit: bool,
    /// Every target has an instance in the map (matched the same way).
    pub targets_in_map: bool,
    /// So has every anchor object the expression relates to (true when it has none).
    pub anchors_in_map: bool,
    /// Single-target expressions: the answer's box IoU with the target's (0 otherwise).
    pub iou: f64,
    /// Referring mIoU over held-out views that see a target (None: none does).
    pub mask_iou: Option<f64>,
    pub millis: f64,
    pub success: bool,
    pub message: String,
    pub reasoner_used: String,
}

pub fn oriented(b: &BoundingBox3D) -> OrientedBox {
    pose_box(&b.center, &b.size)
}

/// A listed instance's box.
pub fn instance_box(i: &Instance) -> OrientedBox {
    pose_box(&i.pose, &i.size)
}

/// The object `b` names: the one it overlaps most, else the nearest within 0.5 m; 0 for none.
pub fn matched_object(b: &OrientedBox, objects: &[TruthObject]) -> (u16, f64) {
    let best = objects
        .iter()
        .map(|o| (o.id, b.iou(&o.bbox)))
        .max_by(|a, c| a.1.total_cmp(&c.1));
    if let Some((id, iou)) = best.filter(|b| b.1 > 0.0) {
        return (id, iou);
    }
    objects
        .iter()
        .map(|o| (o.id, (o.bbox.centre - b.centre).length()))
        .filter(|(_, d)| *d <= MATCH_DISTANCE_M)
        .min_by(|a, c| a.1.total_cmp(&c.1))
        .map_or((0, 0.0), |(id, _)| (id, 0.0))
}

/// Whether the map holds what `e` relates to: both anchors of "between" and of two hops, any
/// one of the others (support relations hold with any instance of the anchor class).
fn anchors_in_map(e: &Expression, in_map: &[u16]) -> bool {
    use groupforward_sim::referring::Relation;
    if matches!(e.relation, Relation::Between | Relation::TwoHop) {
        e.anchors.iter().all(|a| in_map.contains(a))
    } else {
        e.anchors.is_empty() || e.anchors.iter().any(|a| in_map.contains(a))
    }
}

/// The request a client would send for `expression` (its view, if view-dependent).
pub fn request_for(expression: &Expression) -> ReferRequest {
    let mut request = ReferRequest {
        expression: expression.text.clone(),
        ..ReferRequest::default()
    };
    if let Some(view) = expression.view {
        let [x, y, z, w] = view.orientation;
        request.use_view_pose = true;
        request.view_pose = Pose {
            position: Point {
                x: view.position[0],
                y: view.position[1],
                z: view.position[2],
            },
            orientation: Quaternion { x, y, z, w },
        };
    }
    request
}

/// What answers the questions: the names, the text encoder and the `refer` config.
#[derive(Debug, Clone)]
pub struct Referrer {
    pub vocabulary: Option<Vocabulary>,
    pub encoder: Option<Arc<Mutex<TextEncoder>>>,
    pub section: ReferSection,
}

/// A scene's ground truth beside the pipeline: its objects and held-out views.
#[derive(Debug, Clone, Copy)]
pub struct SceneTruth<'a> {
    pub objects: &'a [TruthObject],
    pub views: &'a [HeldOutView],
}

/// Whether `response` refuses with a reason: no instance, and a message saying why.
fn is_refusal(response: &ReferResponse) -> bool {
    !response.success && response.instance_ids.is_empty() && !response.message.trim().is_empty()
}

/// Ask every expression of a scene on its final `map` and score the answers, each by its truth.
impl Referrer {
    /// The node's shared state holding `map`, configured as this referrer (its object list made
    /// once, for the questions and the published masks alike).
    pub fn shared(&self, map: SceneMap) -> Shared {
        let mut shared = Shared {
            vocabulary: self.vocabulary.clone(),
            text_encoder: self.encoder.clone(),
            refer: self.section.clone(),
            world_frame: "map".into(),
            ..Shared::default()
        };
        shared.set_map(map);
        shared
    }
}

/// Mean IoU of the published masks against the ground truth: every listed instance labelled as
/// `~/instance_masks` draws it (the instance whose map points a pixel's measured depth lies on; 0
/// where the sensor read nothing), in the held-out views with measured depth, for each listed
/// instance that found an object (box IoU >= 0.25) in each view where it or its object shows.
/// `None` without measured depth or a found object.
pub fn published_mask_iou(
    shared: &Shared,
    objects: &[TruthObject],
    views: &[HeldOutView],
) -> Option<f64> {
    let index: std::collections::HashMap<&str, usize> = shared
        .map
        .instances
        .iter()
        .enumerate()
        .map(|(k, i)| (i.id.as_str(), k))
        .collect();
    let found: Vec<(usize, u16)> = shared
        .instances
        .iter()
        .filter_map(|i| {
            let (object, iou) = matched_object(&instance_box(i), objects);
            (iou >= FOUND_IOU).then_some((*index.get(i.id.as_str())?, object))
        })
        .collect();
    let instances: Vec<&Gaussians> = shared.map.instances.iter().map(|i| &i.gaussians).collect();
    let chosen: Vec<usize> = found.iter().map(|f| f.0).collect();
    let volume = AnswerVolume::new(&instances, &chosen)?;
    let mut ious = Vec::new();
    for view in views {
        let Some(measured) = view.measured.as_ref() else {
            continue;
        };
        let labels = measured_view_labels(&volume, measured);
        for (k, &(_, object)) in found.iter().enumerate() {
            let label = Some((k + 1) as u16);
            let pairs = labels.iter().zip(&view.truth);
            ious.extend(mask_iou(pairs.map(|(l, t)| (*l == label, *t == object))));
        }
    }
    (!ious.is_empty()).then(|| ious.iter().sum::<f64>() / ious.len() as f64)
}

/// IoU of a predicted and a true mask given pixel by pixel as (predicted, true); `None` when
/// neither holds a pixel.
fn mask_iou(pixels: impl Iterator<Item = (bool, bool)>) -> Option<f64> {
    let (mut inter, mut union) = (0usize, 0usize);
    for (p, t) in pixels {
        inter += usize::from(p && t);
        union += usize::from(p || t);
    }
    (union > 0).then(|| inter as f64 / union as f64)
}

/// A listed instance found an object at this box IoU (`eval map`'s recall@0.25).
const FOUND_IOU: f64 = 0.25;

/// Ask `shared`'s map ([`Referrer::shared`]) every expression through the `Refer` handler and
/// score the answers against `truth`.
pub fn ask_scene(
    scene: &str,
    shared: Shared,
    truth: SceneTruth<'_>,
    expressions: &[(Expression, Truth)],
) -> Vec<ReferRecord> {
    let SceneTruth { objects, views } = truth;
    // The map's instances as objects: which targets the map holds at all.
    let in_map: Vec<u16> = shared
        .instances
        .iter()
        .map(|i| matched_object(&instance_box(i), objects).0)
        .collect();
    let shared = Mutex::new(shared);
    let box_of = |id: &str, shared: &Mutex<Shared>| -> Option<OrientedBox> {
        let s = shared.lock().ok()?;
        s.instances.iter().find(|i| i.id == id).map(instance_box)
    };
    expressions
        .iter()
        .map(|(e, kind)| {
            let request = request_for(e);
            let started = Instant::now();
            let response: ReferResponse = cdr::encode(&request)
                .map_err(|e| e.to_string())
                .and_then(|bytes| handle_refer(&shared, &bytes))
                .and_then(|bytes| cdr::decode(&bytes).map_err(|e| e.to_string()))
                .unwrap_or_else(|message| ReferResponse {
                    message,
                    ..ReferResponse::default()
                });
            let millis = started.elapsed().as_secs_f64() * 1e3;
            let matches: Vec<(u16, f64)> = response
                .boxes
                .iter()
                .map(|b| matched_object(&oriented(b), objects))
                .collect();
            // A duplicate instance of a target names the same object: the answer is right, the
            // duplicate is the map's fault and `eval map` counts it.
            let mut answered: Vec<u16> = matches.iter().map(|m| m.0).collect();
            answered.sort_unstable();
            answered.dedup();
            let candidates: Vec<u16> = response
                .candidates
                .iter()
                .filter_map(|c| box_of(&c.id, &shared))
                .map(|b| matched_object(&b, objects).0)
                .collect();
            let mask_iou = shared.lock().ok().and_then(|s| {
                let instances: Vec<&Gaussians> =
                    s.map.instances.iter().map(|i| &i.gaussians).collect();
                let chosen: Vec<usize> = response
                    .instance_ids
                    .iter()
                    .filter_map(|id| s.map.instances.iter().position(|i| &i.id == id))
                    .collect();
                referring_iou(&instances, &chosen, &e.targets, views)
            });
            let iou = match (&e.targets[..], &matches[..]) {
                ([target], [(id, iou)]) if id == target => *iou,
                _ => 0.0,
            };
            let correct = match kind {
                Truth::Refusal => is_refusal(&response),
                Truth::Observed | Truth::EveryObject => response.success && answered == e.targets,
            };
            ReferRecord {
                scene: scene.into(),
                truth: *kind,
                expression: e.text.clone(),
                relation: serde_json::to_value(e.relation)
                    .ok()
                    .and_then(|v| v.as_str().map(str::to_owned))
                    .unwrap_or_default(),
                view_dependent: e.view_dependent,
                hard: e.distractors > 2,
                distractors: e.distractors,
                targets: e.targets.clone(),
                correct,
                answered,
                topk_hit: e.targets.iter().all(|t| candidates.contains(t)),
                targets_in_map: e.targets.iter().all(|t| in_map.contains(t)),
                // Support relations hold with any anchor of the class: one in the map suffices.
                anchors_in_map: anchors_in_map(e, &in_map),
                iou,
                mask_iou,
                millis,
                success: response.success,
                message: response.message,
                reasoner_used: response.reasoner_used,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use groupforward::frame::WindowInstance;
    use groupforward::graph::FusionParams;

    /// A 1 m high panel of Gaussians at depth `z` and 4 cm behind it (camera frame = world
    /// frame) over x0..x1: a box with a volume to match.
    fn panel(x0: f32, x1: f32, z: f32) -> Gaussians {
        let mut g = Gaussians::with_dims(0, 0);
        for i in 0..=((x1 - x0) / 0.02).round() as usize {
            for j in 0..=50 {
                for depth in [z, z + 0.04] {
                    let p = glam::Vec3::new(x0 + i as f32 * 0.02, -0.5 + j as f32 * 0.02, depth);
                    let (scale, rotation) = (glam::Vec3::splat(0.02), glam::Quat::IDENTITY);
                    g.push(p, 0.99, scale, rotation, glam::Vec3::ONE, &[], &[]);
                }
            }
        }
        g
    }

    #[test]
    fn published_masks_score_high_on_their_own_objects_and_nothing_on_swapped_ones() {
        let mut map = SceneMap::new(FusionParams::default());
        let sides = [(-0.6, -0.02), (0.02, 0.6)];
        for (k, (x0, x1)) in sides.into_iter().enumerate() {
            let sighting = WindowInstance {
                gaussians: panel(x0, x1, 2.0),
                prototype: vec![1.0, k as f32],
                support: 10,
            };
            map.fuse(vec![sighting], &[], k as i64).unwrap();
        }
        let referrer = Referrer {
            vocabulary: None,
            encoder: None,
            section: ReferSection::default(),
        };
        // The objects are where the map lists its instances (boxes are the map's business and
        // `eval map`'s; the masks are scored here): 7 on the left, 9 on the right.
        let shared = referrer.shared(map);
        let objects: Vec<TruthObject> = shared
            .instances
            .iter()
            .map(|i| {
                let bbox = instance_box(i);
                TruthObject {
                    id: if bbox.centre.x < 0.0 { 7 } else { 9 },
                    class: "wall".into(),
                    bbox,
                    pixels: 10_000,
                }
            })
            .collect();
        assert_eq!(objects.len(), 2);
        // The sensor saw both panels at 2 m; the truth image has object 7 on the left of x = 0.
        let camera = Camera::from_fov(64, 48, 1.2).unwrap();
        let column_x = |u: usize| (u as f64 - camera.cx) / camera.fx * 2.0;
        let truth_of = |left: u16, right: u16| -> Vec<u16> {
            (0..64 * 48)
                .map(|p| {
                    let (x, y) = (column_x(p % 64), (p / 64) as f64);
                    let y = (y - camera.cy) / camera.fy * 2.0;
                    match (x, y.abs() <= 0.5) {
                        (x, true) if (-0.6..-0.02).contains(&x) => left,
                        (x, true) if (0.02..0.6).contains(&x) => right,
                        _ => 0,
                    }
                })
                .collect()
        };
        let keyframe = Keyframe {
            stamp_nanos: 1,
            camera,
            world_from_camera: Rigid::default(),
        };
        let view = |truth: Vec<u16>| HeldOutView {
            keyframe: keyframe.clone(),
            truth,
            measured: Some(MeasuredDepth::new(
                keyframe.clone(),
                vec![2.0; 64 * 48],
                None,
            )),
            scene_depth: Vec::new(),
        };
        let right = published_mask_iou(&shared, &objects, &[view(truth_of(7, 9))]);
        assert!(right.is_some_and(|iou| iou > 0.8), "{right:?}");
        let swapped = published_mask_iou(&shared, &objects, &[view(truth_of(9, 7))]);
        assert!(swapped.is_some_and(|iou| iou < 0.05), "{swapped:?}");
        // Without measured depth there is nothing to score.
        let mut blind = view(truth_of(7, 9));
        blind.measured = None;
        assert_eq!(published_mask_iou(&shared, &objects, &[blind]), None);
    }

    #[test]
    fn only_an_answer_without_instances_that_says_why_is_a_refusal() {
        let refused = ReferResponse {
            success: false,
            message: "no lamp has been seen".into(),
            ..ReferResponse::default()
        };
        assert!(is_refusal(&refused));
        let silent = ReferResponse {
            message: "  ".into(),
            ..refused.clone()
        };
        assert!(!is_refusal(&silent));
        let answered = ReferResponse {
            success: true,
            instance_ids: vec!["inst_000001".into()],
            ..refused.clone()
        };
        assert!(!is_refusal(&answered));
        let failed_with_an_instance = ReferResponse {
            instance_ids: vec!["inst_000001".into()],
            ..refused
        };
        assert!(!is_refusal(&failed_with_an_instance));
    }
}
