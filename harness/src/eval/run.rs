//! A sim scene through the node's stages, for evaluation: the simulator records the scene as a
//! rosbag2 bag (without its ground-truth topics), and every message of the bag goes through the
//! node's ingest, keyframe selection, window pass and fusion in order, synchronously, so every
//! window is processed (the live node drops windows that arrive while its worker is busy) and a
//! run is reproducible. Ground truth is read from the simulator beside the pipeline, only to
//! score what came out.

use std::collections::{BTreeMap, HashMap};

use groupforward_sim::record::{record_to_memory, RecordOptions};
use groupforward_sim::render::{PlacedObject, Scene};
use groupforward_sim::scene::SceneFile;
use groupforward_sim::simulation::Simulation;
use rayon::prelude::*;

use super::score::{ListedInstance, TruthObject, WindowRecord, UNASSIGNED_REASONS};
use groupforward::config::Config;
use groupforward::frame::SyncedFrame;
use groupforward::graph::listing::object_list;
use groupforward::graph::{GraphError, SceneMap};
use groupforward::ingest::{DepthValidity, Ingest};
use groupforward::node::Node;
use groupforward::recon::boxes::{OrientedBox, DEFAULT_TRIM};
use groupforward::recon::depth_noise;
use groupforward::recon::metrics::{object_coverage, sample_nearest, ObjectCoverage};
use groupforward::timing::{Stage, StageTimes};
use groupforward::window::{Unassigned, WindowError, WindowModels, WindowOutput};

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("scene `{0}`: {1}")]
    Sim(String, String),
    #[error("reading the recorded bag: {0}")]
    Bag(String),
    #[error(transparent)]
    Window(#[from] WindowError),
    #[error(transparent)]
    Graph(#[from] GraphError),
    #[error(transparent)]
    Model(#[from] groupforward::model::ModelError),
}

/// Everything one scene's run gives the scorer.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneRun {
    pub scene: String,
    pub room_area: f64,
    pub objects: Vec<TruthObject>,
    /// The final map's object list as the node publishes it.
    pub instances: Vec<ListedInstance>,
    pub windows: Vec<WindowRecord>,
    /// Model pass to map update, per window and stage.
    pub window_times: Vec<StageTimes>,
    pub frames: usize,
    /// Depth pixels ingest received, and why some were invalid.
    pub depth: DepthValidity,
    /// Window pixels (model resolution) without valid sensor depth, and how many of them were
    /// lifted at a measured neighbour's depth because the model's depth agrees with it.
    pub model_pixels_without_depth: u64,
    pub lifted_at_neighbour_depth: u64,
    /// Per window, the depth noise at 1 m its views measured (median; `None` where none did).
    pub depth_noise_at_1m: Vec<Option<f32>>,
    /// The final map (what referring queries are asked on).
    pub map: SceneMap,
}

/// The ground-truth box of a placed object: the union of its parts in its own frame, scaled,
/// turned by its yaw.
pub fn truth_box(object: &PlacedObject) -> OrientedBox {
    match object.oriented_extent() {
        Some((centre, size)) => OrientedBox {
            centre,
            size,
            yaw: object.yaw,
        }
        .canonical(),
        None => OrientedBox::from_bounds(object.position, object.position),
    }
}

/// The scene's objects as the scorer sees them: class name, ground-truth box, and the pixels
/// `pixels` reports for each instance id.
pub fn truth_objects(scene: &Scene, pixels: impl Fn(u16) -> u64) -> Vec<TruthObject> {
    let classes = groupforward_sim::library::classes();
    scene
        .objects
        .iter()
        .map(|o| TruthObject {
            id: o.instance_id,
            class: classes
                .iter()
                .find(|c| c.id == o.class_id)
                .map_or("object", |c| c.name)
                .to_owned(),
            bbox: truth_box(o),
            pixels: pixels(o.instance_id),
        })
        .collect()
}

/// A scene recorded once, to be replayed under several settings: its bag (no ground-truth
/// topics) and, beside it, the ground truth the scorer reads.
#[derive(Debug, Clone)]
pub struct RecordedScene {
    pub scene: String,
    pub room_area: f64,
    pub objects: Vec<TruthObject>,
    pub frames: usize,
    bag: Vec<u8>,
    /// Object pixels per frame, by the stamp the frame's messages carry.
    frame_pixels: HashMap<i64, BTreeMap<u16, u64>>,
    /// Each frame's instance ids (its first camera's, full resolution; 0 where no object), by
    /// stamp: where each object's pixels went in a window ([`WindowRecord::coverage`]).
    frame_truth: HashMap<i64, TruthImage>,
}

/// One view's ground-truth instance ids.
#[derive(Debug, Clone)]
struct TruthImage {
    width: usize,
    height: usize,
    instance: Vec<u16>,
}

/// Run `file` through the node's stages with `models`; `config` gives the topics, ingest and
/// window settings (its model paths are not read: `models` is loaded once for all scenes).
pub fn run_scene(
    file: &SceneFile,
    config: &Config,
    models: &mut WindowModels,
) -> Result<SceneRun, EvalError> {
    replay_scene(&record_scene(file)?, config, models)
}

/// Render and record `file` as the node would receive it, with the ground truth beside it.
pub fn record_scene(file: &SceneFile) -> Result<RecordedScene, EvalError> {
    let sim_error = |e: String| EvalError::Sim(file.name.clone(), e);
    let sim = Simulation::new(file.clone()).map_err(|e| sim_error(e.to_string()))?;
    let options = RecordOptions {
        ground_truth: false,
        ..RecordOptions::default()
    };
    let (bag, _) = record_to_memory(&sim, &options).map_err(|e| sim_error(e.to_string()))?;
    // Ground truth beside the pipeline: each frame's object pixels, by the stamp its messages carry.
    let per_frame: Vec<(i64, BTreeMap<u16, u64>, Option<TruthImage>)> = (0..sim.frame_count())
        .into_par_iter()
        .map(|i| {
            let frame = sim.frame(i);
            let mut pixels = BTreeMap::new();
            for view in &frame.views {
                for &id in view.truth.instance.iter().filter(|&&id| id > 0) {
                    *pixels.entry(id).or_insert(0u64) += 1;
                }
            }
            let stamp = options.start_nanos + (frame.stamp_secs * 1e9).round() as i64;
            let truth = frame.views.first().map(|v| TruthImage {
                width: v.truth.width as usize,
                height: v.truth.height as usize,
                instance: v.truth.instance.clone(),
            });
            (stamp, pixels, truth)
        })
        .collect();
    let mut total: BTreeMap<u16, u64> = BTreeMap::new();
    for (_, pixels, _) in &per_frame {
        for (id, n) in pixels.iter() {
            *total.entry(*id).or_default() += n;
        }
    }
    let objects = truth_objects(&sim.scene, |id| total.get(&id).copied().unwrap_or(0));
    let mut frame_pixels = HashMap::with_capacity(per_frame.len());
    let mut frame_truth = HashMap::with_capacity(per_frame.len());
    for (stamp, pixels, truth) in per_frame {
        frame_pixels.insert(stamp, pixels);
        if let Some(truth) = truth {
            frame_truth.insert(stamp, truth);
        }
    }
    let room = file.room.size;
    Ok(RecordedScene {
        scene: file.name.clone(),
        room_area: room[0] * room[1],
        objects,
        frames: sim.frame_count(),
        bag,
        frame_pixels,
        frame_truth,
    })
}

/// Replay a recorded scene through the node's stages with `models` and `config` (see
/// [`run_scene`]).
pub fn replay_scene(
    recorded: &RecordedScene,
    config: &Config,
    models: &mut WindowModels,
) -> Result<SceneRun, EvalError> {
    replay_scene_with(recorded, config, models, |_, _, _| Ok(()))
}

/// [`replay_scene`], handing each window's frames and pass output (before fusion) with the
/// models to `on_window`: what a baseline built from the same passes needs.
pub fn replay_scene_with(
    recorded: &RecordedScene,
    config: &Config,
    models: &mut WindowModels,
    mut on_window: impl FnMut(&[SyncedFrame], &WindowOutput, &mut WindowModels) -> Result<(), EvalError>,
) -> Result<SceneRun, EvalError> {
    let frame_pixels = &recorded.frame_pixels;

    let routes: HashMap<String, groupforward::ingest::Route> =
        Ingest::routes(&config.cameras, &config.tf)
            .into_iter()
            .collect();
    let mut node = Node::new(config);
    let mut map = SceneMap::default();
    let mut windows = Vec::new();
    let mut window_times = Vec::new();
    let (mut model_pixels_without_depth, mut lifted_at_neighbour_depth) = (0u64, 0u64);
    let mut depth_noise_at_1m = Vec::new();
    let mut ahead = Vec::new();
    models.set_views(config.window.views);
    let mut stream =
        mcap::MessageStream::new(&recorded.bag).map_err(|e| EvalError::Bag(e.to_string()))?;
    let mut ended = false;
    while !ended {
        let ready = match stream.next() {
            Some(message) => {
                let message = message.map_err(|e| EvalError::Bag(e.to_string()))?;
                let Some(route) = routes.get(&message.channel.topic) else {
                    continue;
                };
                let step = node.step(*route, &message.data);
                // As the node's worker does: features of each keyframe when it arrives, not in
                // its window.
                for frame in step
                    .keyframes
                    .iter()
                    .filter(|_| config.window.features_ahead)
                {
                    if let Some(took) = models.prepare(frame) {
                        ahead.push(took);
                    }
                }
                step.windows
            }
            // As the node does when a stream ends: the keyframes short of a window are mapped.
            None => {
                ended = true;
                node.pending_windows()
            }
        };
        for frames in ready {
            let stamp = frames.last().map_or(0, |f| f.stamp_nanos);
            let mut seen: BTreeMap<u16, u64> = BTreeMap::new();
            for frame in &frames {
                for (id, n) in frame_pixels
                    .get(&frame.stamp_nanos)
                    .into_iter()
                    .flat_map(|p| p.iter())
                {
                    *seen.entry(*id).or_default() += n;
                }
            }
            let mut output = models.pass(&frames)?;
            model_pixels_without_depth +=
                (output.invalid_depth_pixels + output.neighbour_depth_pixels) as u64;
            lifted_at_neighbour_depth += output.neighbour_depth_pixels as u64;
            depth_noise_at_1m.push(depth_noise::median_measured(
                output.views.iter().map(|v| v.depth_noise_at_1m),
            ));
            on_window(&frames, &output, models)?;
            let pixel_instances = std::mem::take(&mut output.pixel_instances);
            let model_size = output.views.first().map_or((0, 0), |v| {
                let camera = &v.keyframe.camera;
                (camera.width as usize, camera.height as usize)
            });
            // Scoring's boxes, outside the timed stages.
            let boxes: Vec<OrientedBox> = output
                .instances
                .iter()
                .map(|i| OrientedBox::fit(&i.gaussians.means, DEFAULT_TRIM))
                .collect();
            let mut times = output.times;
            let report = times.time(Stage::Fusion, || {
                models.fuse(&mut map, output.instances, &output.views, stamp)
            })?;
            times.0.push((Stage::Window, times.total()));
            // The work done ahead for this window's keyframes, outside its latency.
            times
                .0
                .extend(ahead.drain(..).map(|took| (Stage::Keyframe, took)));
            window_times.push(times);
            let (coverage, unassigned) =
                window_coverage(&recorded.frame_truth, &frames, model_size, &pixel_instances);
            windows.push(WindowRecord {
                coverage,
                unassigned,
                objects: seen.into_iter().collect(),
                instances: boxes.into_iter().zip(report.assigned).collect(),
                map: listed_instances(&map, models),
                folds: report.absorbed,
            });
        }
    }
    let mut depth = DepthValidity::default();
    for camera in 0..node.ingest.camera_count() {
        if let Some(counters) = node.ingest.camera_counters(camera) {
            depth.add(&counters.depth);
        }
    }
    let instances = listed_instances(&map, models);
    Ok(SceneRun {
        scene: recorded.scene.clone(),
        room_area: recorded.room_area,
        objects: recorded.objects.clone(),
        instances,
        windows,
        window_times,
        frames: recorded.frames,
        depth,
        model_pixels_without_depth,
        lifted_at_neighbour_depth,
        depth_noise_at_1m,
        map,
    })
}

/// Per object of a window: where its pixels went ([`ObjectCoverage`]) and, of those in no
/// instance, how many each stage dropped (model pixels, in [`Unassigned::ALL`]'s order).
type WindowCoverage = (Vec<ObjectCoverage>, Vec<(u16, [u64; UNASSIGNED_REASONS])>);

/// Where each object's pixels went in one window's instances (at the model's resolution, the
/// truth sampled at its pixel centres as `eval window` does); empty when the window lifted
/// nothing or a frame's truth is missing.
fn window_coverage(
    truth: &HashMap<i64, TruthImage>,
    frames: &[SyncedFrame],
    model_size: (usize, usize),
    pixel_instances: &[i32],
) -> WindowCoverage {
    let (width, height) = model_size;
    if width * height * frames.len() != pixel_instances.len() {
        return WindowCoverage::default();
    }
    let mut truth_ids = Vec::with_capacity(pixel_instances.len());
    for frame in frames {
        let Some(image) = truth.get(&frame.stamp_nanos) else {
            return WindowCoverage::default();
        };
        let sampled = sample_nearest(
            &image.instance,
            (image.width, image.height),
            (width, height),
        );
        truth_ids.extend(sampled.into_iter().map(u32::from));
    }
    let predicted: Vec<u32> = pixel_instances
        .iter()
        .map(|&k| u32::try_from(k).unwrap_or(u32::MAX))
        .collect();
    let coverage = object_coverage(&predicted, &truth_ids, u32::MAX, 0, 1).unwrap_or_default();
    // Why each object's pixels in no instance went to none.
    let mut unassigned: BTreeMap<u16, [u64; UNASSIGNED_REASONS]> = BTreeMap::new();
    for (&code, &object) in pixel_instances.iter().zip(&truth_ids) {
        if let (Some(reason), true) = (Unassigned::of_code(code), object > 0) {
            let slot = Unassigned::ALL
                .iter()
                .position(|r| *r == reason)
                .unwrap_or(0);
            unassigned.entry(object as u16).or_default()[slot] += 1;
        }
    }
    (coverage, unassigned.into_iter().collect())
}

/// The map's object list as the node publishes it ([`object_list`]), each instance with its best
/// name and its box.
fn listed_instances(map: &SceneMap, models: &WindowModels) -> Vec<ListedInstance> {
    let vocabulary = models.vocabulary.as_ref();
    object_list(map, vocabulary, |i, box_like| i.fitted(box_like))
        .into_iter()
        .map(|listed| {
            let (i, bbox) = (listed.instance, listed.bbox);
            let (name, name_score) = vocabulary
                .and_then(|v| v.ranked(&listed.names, 1).into_iter().next())
                .unwrap_or_default();
            ListedInstance {
                id: i.id.clone(),
                name,
                name_score: f64::from(name_score),
                observations: i.observations,
                gaussians: i.gaussians.len(),
                bbox,
            }
        })
        .collect()
}
