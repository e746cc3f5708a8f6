//! The rolling window: keyframe selection, one reconstruction-model pass per window,
//! grouping of the embeddings, and the window instances and views that fusion takes.
//!
//! Frames become keyframes when the camera has moved at least `min_translation_m` or turned
//! `min_rotation_deg` since the last keyframe, or `max_interval_secs` passed. A window is the
//! newest keyframe and the `views − 1` keyframes before it (the most recent ones: on a moving robot
//! these are the most covisible; a covisibility ranking is future work).
//!
//! Keyframes still short of a window when the camera's stream pauses or ends (`flush_after_secs`
//! with no synced frame, or the node stopping) are not left unmapped: the newest `views` keyframes
//! then form one more window, overlapping the previous one (fusion merges what it sees twice).
//!
//! One pass ([`pass_with_cache`]) runs in named steps: the model over the views (the newest
//! view's semantic features beside it), lifting to Gaussians, HDBSCAN on the embeddings, cleaning
//! (flying pixels, specks, support bleed), the semantic prototypes, and the window's instances and
//! views for fusion. [`keyframes`] selects the frames, [`features`] caches and pools semantic
//! features, [`models`] loads what a pass runs on.

mod features;
mod keyframes;
mod models;

use crate::frame::{Keyframe, SyncedFrame, WindowInstance, WindowView};
use crate::group::cleaning::{
    drop_other_objects, drop_support_bleed, floor_height, flying_pixels, split_components,
    CleaningParams,
};
use crate::group::semantics::{Vocabulary, OTHER_PHRASE};
use crate::group::votes::split_by_votes;
use crate::group::{group, GroupError, GroupingParams};
use crate::model::manifest::InputMode;
use crate::model::reconstruction::{
    lifted_pixels, resized_camera, use_sensor_depth, Prediction, ReconstructionModel, View,
};
use crate::model::semantic::SemanticModel;
use crate::model::ModelError;
use crate::recon::depth_noise;
use crate::recon::gaussians::Gaussians;
use crate::recon::median;
use crate::timing::{Stage, StageTimes};
use features::{instance_prototypes_of, point_classes, window_features};
use serde::{Deserialize, Serialize};

pub use features::{feature_classes, FeatureCache, KeyframeFeatures};
pub use keyframes::Keyframes;
pub use models::WindowModels;

#[derive(Debug, thiserror::Error)]
pub enum WindowError {
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Group(#[from] GroupError),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WindowSection {
    /// Views per model pass (2–24).
    pub views: usize,
    /// A frame is a keyframe once the camera moved this far (m) since the last one, ...
    pub min_translation_m: f64,
    /// ... or turned this much (degrees), ...
    pub min_rotation_deg: f64,
    /// ... or this long passed (s). The three defaults are the first ones' 0.7 (0.2 m, 15°,
    /// 1 s before): a walk that turns while it looks keeps more of what it glimpsed, at 1.4
    /// windows where there was one. Read on benchmark 15200-15219 and layouts 920-939 against
    /// 0.5 (recall@0.25 +7.4 and +3.6 points for precision -0.9 and -2.0, where 0.5 bought +8.5
    /// and +5.9 for -3.9 and -4.9); fresh on 15400-15419 and layouts 940-959: +3.1 and +5.9.
    pub max_interval_secs: f64,
    /// Keyframes kept for windows.
    pub max_keyframes: usize,
    /// Compute each keyframe's semantic features when it arrives (while the worker would wait),
    /// so a window pass only computes its newest view's; off: every view's in the pass.
    pub features_ahead: bool,
    /// Bring each keyframe's colour to the camera's running exposure (auto-exposure hunting),
    /// measured on the surface it shares with the previous keyframe ([`crate::exposure`]).
    pub exposure_compensation: bool,
    /// A camera with keyframes waiting for a window and no synced frame for this long (s): its
    /// stream paused or ended, so its newest `views` keyframes form a window now. 0 or less: only
    /// when the node stops.
    pub flush_after_secs: f64,
}

impl Default for WindowSection {
    fn default() -> Self {
        Self {
            views: 4,
            min_translation_m: 0.14,
            min_rotation_deg: 10.0,
            max_interval_secs: 0.7,
            max_keyframes: 32,
            features_ahead: true,
            exposure_compensation: true,
            flush_after_secs: 1.0,
        }
    }
}

/// What one window pass produced.
#[derive(Debug, Clone, PartialEq)]
pub struct WindowOutput {
    pub instances: Vec<WindowInstance>,
    pub views: Vec<WindowView>,
    pub gaussians: usize,
    pub noise: usize,
    /// Why this window's instances carry no semantic prototype, when a semantic model was given
    /// but failed (the window is kept: geometry alone then associates it).
    pub semantics_error: Option<String>,
    /// RGB-D: model pixels without valid sensor depth (ingest marked them) that were not lifted.
    pub invalid_depth_pixels: usize,
    /// RGB-D: model pixels without valid sensor depth lifted at a measured neighbour's depth,
    /// where the model's own depth agrees with it
    /// ([`crate::model::reconstruction::MODEL_DEPTH_AGREEMENT`]).
    pub neighbour_depth_pixels: usize,
    /// Why the window built nothing (no valid depth in any view); `None` when it ran.
    pub skipped: Option<String>,
    /// Views whose semantic features came computed ahead from the keyframe cache.
    pub features_cached: usize,
    /// The model's own depth per model pixel (view-major), before RGB-D mode replaces it by the
    /// sensor's: what `eval window` scores.
    pub model_depth: Vec<f32>,
    /// Per model pixel (view-major): the index of the instance in `instances` its Gaussian went
    /// to, or a negative [`Unassigned`] code saying why it went to none.
    pub pixel_instances: Vec<i32>,
    /// Time per stage of this pass.
    pub times: StageTimes,
}

/// Why a model pixel is in no window instance: the negative codes of
/// [`WindowOutput::pixel_instances`], one per stage that can drop a pixel, in pipeline order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(i32)]
pub enum Unassigned {
    /// No Gaussian: no valid depth (RGB-D) or not lifted.
    NotLifted = -1,
    /// HDBSCAN's noise, or farther than `noise_distance` from every centroid.
    Noise = -2,
    /// A flying pixel at a depth edge, or a nearly transparent Gaussian.
    Edge = -3,
    /// A 3D connected part of its cluster too small to be an object.
    Speck = -4,
    /// Floor around an object's foot (support bleed).
    Support = -5,
    /// A point the semantic model calls another object than its instance's.
    OtherObject = -6,
}

impl Unassigned {
    pub const ALL: [Unassigned; 6] = [
        Unassigned::NotLifted,
        Unassigned::Noise,
        Unassigned::Edge,
        Unassigned::Speck,
        Unassigned::Support,
        Unassigned::OtherObject,
    ];

    /// The reason a `pixel_instances` code stands for; `None` for an instance index.
    pub fn of_code(code: i32) -> Option<Self> {
        Self::ALL.into_iter().find(|r| *r as i32 == code)
    }

    pub fn name(self) -> &'static str {
        match self {
            Unassigned::NotLifted => "not_lifted",
            Unassigned::Noise => "noise",
            Unassigned::Edge => "edge",
            Unassigned::Speck => "speck",
            Unassigned::Support => "support",
            Unassigned::OtherObject => "other_object",
        }
    }
}

/// Mark in `why` the points a stage took out of every cluster (`before` assigned, `after` not).
fn mark_dropped(before: &[i32], after: &[i32], why: &mut [Unassigned], reason: Unassigned) {
    for ((b, a), w) in before.iter().zip(after).zip(why.iter_mut()) {
        if *b >= 0 && *a < 0 {
            *w = reason;
        }
    }
}

/// Run the model on `frames`, group the embeddings, and split the Gaussians by instance. With a
/// semantic model, each instance also gets its prototype: the masked mean of the views' semantic
/// features over the instance's pixels (§5.5); without one, fusion associates by geometry alone.
pub fn window_pass(
    model: &mut ReconstructionModel,
    semantic: Option<&mut SemanticModel>,
    frames: &[SyncedFrame],
    grouping: &GroupingParams,
) -> Result<WindowOutput, WindowError> {
    let mut no_cache = FeatureCache::default();
    pass_with_cache(
        model,
        semantic.map(|m| (m, &mut no_cache)),
        None,
        frames,
        grouping,
    )
}

/// [`window_pass`] with a cache of keyframe features computed ahead (see [`FeatureCache`]); with
/// the `vocabulary` that names instances, the points of an object's instance that the semantic
/// model calls another object become noise ([`drop_other_objects`]).
pub fn pass_with_cache(
    model: &mut ReconstructionModel,
    semantic: Option<(&mut SemanticModel, &mut FeatureCache)>,
    vocabulary: Option<&Vocabulary>,
    frames: &[SyncedFrame],
    grouping: &GroupingParams,
) -> Result<WindowOutput, WindowError> {
    let mut times = StageTimes::default();
    let views: Vec<View<'_>> = frames.iter().map(View::from).collect();
    let (prediction, features) =
        predict_beside_features(model, semantic, vocabulary, frames, &views, &mut times);
    let mut prediction = prediction?;
    let model_depth = prediction.depth.clone();
    let lifted = times.time(Stage::Lift, || lift(model, &mut prediction, &views));
    let (gaussians, invalid_depth_pixels, neighbour_depth_pixels) = lifted?;
    if gaussians.is_empty() {
        return Ok(WindowOutput {
            instances: Vec::new(),
            views: Vec::new(),
            gaussians: 0,
            noise: 0,
            semantics_error: None,
            invalid_depth_pixels,
            neighbour_depth_pixels,
            skipped: Some(format!(
                "no valid depth in any of the {} views: nothing to lift",
                frames.len()
            )),
            features_cached: 0,
            model_depth,
            pixel_instances: Vec::new(),
            times,
        });
    }
    let pixels = lifted_pixels(&prediction);
    let grouped = times.time(Stage::Group, || {
        let mut grouped = group(
            &gaussians.embeddings,
            gaussians.embedding_dim.max(1),
            grouping,
        )?;
        if let (Some(split), Some(votes)) = (&grouping.vote_split, &prediction.votes) {
            let scale = model.points_scale();
            let votes = votes.of_pixels(&pixels, prediction.width, prediction.height, scale);
            split_by_votes(&mut grouped.labels, &votes, split);
        }
        Ok::<_, GroupError>(grouped)
    })?;
    let clean_started = std::time::Instant::now();
    let cleaned = clean(grouped.labels, &gaussians, &prediction, &pixels, frames);
    times.0.push((Stage::Clean, clean_started.elapsed()));
    let semantics_started = std::time::Instant::now();
    let Cleaned {
        mut labels,
        mut why,
        clusters,
    } = cleaned;
    let size = (prediction.width, prediction.height);
    let named = features.map(|(features, cached)| {
        let lifted = LiftedLabels {
            pixels: &pixels,
            size,
            clusters,
        };
        (
            name_instances(features, vocabulary, lifted, &mut labels, &mut why),
            cached,
        )
    });
    times
        .0
        .push((Stage::Semantics, semantics_started.elapsed()));
    let (instance_prototypes, semantics_error, features_cached) = match named {
        None => (Vec::new(), None, 0),
        Some((Ok(prototypes), cached)) => (prototypes, None, cached),
        Some((Err(e), cached)) => (Vec::new(), Some(e), cached),
    };
    let (per_instance, noise) = split_by_instance(&gaussians, &labels, clusters);
    let pixel_instances = pixel_instances(
        prediction.depth.len(),
        &pixels,
        &labels,
        &why,
        &per_instance,
    );
    let instances = per_instance
        .into_iter()
        .enumerate()
        .filter(|(_, g)| !g.is_empty())
        .map(|(k, g)| WindowInstance {
            support: g.len(),
            gaussians: g,
            prototype: instance_prototypes.get(k).cloned().unwrap_or_default(),
        })
        .collect();
    Ok(WindowOutput {
        instances,
        views: window_views(frames, &prediction),
        gaussians: gaussians.len(),
        noise,
        semantics_error,
        invalid_depth_pixels,
        neighbour_depth_pixels,
        skipped: None,
        features_cached,
        model_depth,
        pixel_instances,
        times,
    })
}

/// The semantic features of a window's views (or why there are none), and how many of them came
/// computed ahead from the cache.
type ViewFeatures = (Result<Vec<KeyframeFeatures>, ModelError>, usize);

/// The semantic features the window still lacks (the newest keyframe's: it completes the
/// window, so it was not computed ahead) are computed beside the reconstruction model's pass,
/// whose two threads leave a core idle part of the time. Returns the model's prediction and,
/// with a semantic model, the views' features and how many came from the cache.
fn predict_beside_features(
    model: &mut ReconstructionModel,
    semantic: Option<(&mut SemanticModel, &mut FeatureCache)>,
    vocabulary: Option<&Vocabulary>,
    frames: &[SyncedFrame],
    views: &[View<'_>],
    times: &mut StageTimes,
) -> (Result<Prediction, ModelError>, Option<ViewFeatures>) {
    std::thread::scope(|scope| {
        let features = semantic.map(|(semantic, cache)| {
            scope.spawn(move || window_features(semantic, cache, vocabulary, frames))
        });
        let prediction = times.time(Stage::Model, || model.predict(views));
        let features = features.map(|handle| {
            handle.join().unwrap_or_else(|_| {
                let lost = ModelError::Input("the semantic features' thread panicked".into());
                (Err(lost), 0)
            })
        });
        (prediction, features)
    })
}

/// The prediction lifted to Gaussians. RGB-D: geometry from the depth camera (the eval's recall
/// at IoU 0.5 doubles against the model's own depth), instances from the model. Returns the
/// Gaussians, the model pixels without valid depth, and those lifted at a neighbour's depth.
fn lift(
    model: &ReconstructionModel,
    prediction: &mut Prediction,
    views: &[View<'_>],
) -> Result<(Gaussians, usize, usize), ModelError> {
    let from_neighbours = if model.mode() == InputMode::Rgbd {
        use_sensor_depth(prediction, views)
    } else {
        0
    };
    let invalid = prediction
        .depth
        .iter()
        .filter(|d| !(d.is_finite() && **d > 0.0))
        .count();
    model
        .to_gaussians(prediction, views)
        .map(|g| (g, invalid, from_neighbours))
}

/// Cluster labels after cleaning, why each unassigned point is unassigned, and the number of
/// clusters (labels index them; some may be empty).
struct Cleaned {
    labels: Vec<i32>,
    why: Vec<Unassigned>,
    clusters: usize,
}

/// Map hygiene: no flying pixels or transparent Gaussians in objects, a cluster that falls apart
/// in space becomes its parts, and the floor around an object's foot leaves it.
fn clean(
    mut labels: Vec<i32>,
    gaussians: &Gaussians,
    prediction: &Prediction,
    pixels: &[usize],
    frames: &[SyncedFrame],
) -> Cleaned {
    let (w, h) = (prediction.width, prediction.height);
    let cleaning = CleaningParams::default();
    let flying = flying_pixels(&prediction.depth, w, h, cleaning.flying_ratio);
    // Why each point ends in no instance, by the first stage that dropped it.
    let mut why = vec![Unassigned::Noise; labels.len()];
    for (i, label) in labels.iter_mut().enumerate() {
        let at_edge = pixels.get(i).is_none_or(|&p| flying[p]);
        if at_edge || gaussians.opacities[i] < cleaning.min_opacity {
            if *label >= 0 {
                why[i] = Unassigned::Edge;
            }
            *label = -1;
        }
    }
    // The grid must be coarser than a pixel's footprint on the surface, or neighbouring pixels of
    // one surface fall apart (small model resolutions, far surfaces).
    let mut depths: Vec<f32> = pixels.iter().map(|&p| prediction.depth[p]).collect();
    let focal = frames
        .iter()
        .map(|f| resized_camera(&f.camera, w, h).fx)
        .fold(f64::INFINITY, f64::min);
    let footprint = median(&mut depths).map_or(0.0, |d| f64::from(d) / focal) as f32;
    let cell = cleaning.cell.max(3.0 * footprint);
    let before = labels.clone();
    let clusters = split_components(
        &mut labels,
        &gaussians.means,
        cell,
        cleaning.min_part_points,
    );
    mark_dropped(&before, &labels, &mut why, Unassigned::Speck);
    if let Some(floor) = floor_height(&gaussians.means) {
        let before = labels.clone();
        drop_support_bleed(
            &mut labels,
            &gaussians.means,
            clusters,
            floor,
            cleaning.support_slab,
            cleaning.support_margin,
        );
        mark_dropped(&before, &labels, &mut why, Unassigned::Support);
    }
    Cleaned {
        labels,
        why,
        clusters,
    }
}

/// Where the labelled points came from: each point's model pixel (view-major) in model images of
/// `size`, and the number of clusters.
#[derive(Debug, Clone, Copy)]
struct LiftedLabels<'a> {
    pixels: &'a [usize],
    size: (usize, usize),
    clusters: usize,
}

/// The instances' semantic prototypes from the views' features. With a vocabulary, instances of
/// one kind of thing: what the semantic model calls another object leaves an object's instance (a
/// chair's legs grouped with the table they touch). Errors are the window's semantics error.
fn name_instances(
    features: Result<Vec<KeyframeFeatures>, ModelError>,
    vocabulary: Option<&Vocabulary>,
    lifted: LiftedLabels<'_>,
    labels: &mut [i32],
    why: &mut [Unassigned],
) -> Result<Vec<Vec<f32>>, String> {
    let features = features.map_err(|e| e.to_string())?;
    if let Some(vocabulary) = vocabulary {
        let classes = point_classes(&features, lifted.pixels, lifted.size);
        let other = vocabulary
            .phrases
            .iter()
            .position(|p| p == OTHER_PHRASE)
            .unwrap_or(vocabulary.phrases.len()) as u32;
        let before = labels.to_vec();
        drop_other_objects(labels, &classes, lifted.clusters, other);
        mark_dropped(&before, labels, why, Unassigned::OtherObject);
    }
    instance_prototypes_of(
        &features,
        lifted.pixels,
        labels,
        lifted.size,
        lifted.clusters,
    )
    .map_err(|e| e.to_string())
}

/// The Gaussians of each cluster (empty ones included, so indices are cluster labels), and the
/// number of points in none.
fn split_by_instance(
    gaussians: &Gaussians,
    labels: &[i32],
    clusters: usize,
) -> (Vec<Gaussians>, usize) {
    let mut per_instance: Vec<Gaussians> =
        (0..clusters).map(|_| Gaussians::with_dims(0, 0)).collect();
    let mut noise = 0;
    for (i, &label) in labels.iter().enumerate() {
        let Ok(k) = usize::try_from(label) else {
            noise += 1;
            continue;
        };
        per_instance[k].push(
            gaussians.means[i],
            gaussians.opacities[i],
            gaussians.scales[i],
            gaussians.rotations[i],
            gaussians.colors[i],
            &[],
            &[],
        );
    }
    (per_instance, noise)
}

/// Per model pixel (`len` of them, view-major): the index of the window instance its Gaussian went
/// to (clusters left empty are dropped, so instance indices count the kept ones), or why it went
/// to none.
fn pixel_instances(
    len: usize,
    pixels: &[usize],
    labels: &[i32],
    why: &[Unassigned],
    per_instance: &[Gaussians],
) -> Vec<i32> {
    let mut instance_of_cluster = vec![-1i32; per_instance.len()];
    let mut kept = 0;
    for (k, g) in per_instance.iter().enumerate() {
        if !g.is_empty() {
            instance_of_cluster[k] = kept;
            kept += 1;
        }
    }
    let mut pixel_instances = vec![Unassigned::NotLifted as i32; len];
    for ((&pixel, &label), &reason) in pixels.iter().zip(labels).zip(why) {
        if let Some(slot) = pixel_instances.get_mut(pixel) {
            *slot = match usize::try_from(label) {
                Ok(k) => instance_of_cluster[k],
                Err(_) => reason as i32,
            };
        }
    }
    pixel_instances
}

/// The window's views as fusion takes them: keyframes at the model's resolution, the lifted
/// depth, and the range noise each view's sensor depth shows.
fn window_views(frames: &[SyncedFrame], prediction: &Prediction) -> Vec<WindowView> {
    let (w, h) = (prediction.width, prediction.height);
    frames
        .iter()
        .enumerate()
        .map(|(v, f)| WindowView {
            keyframe: Keyframe {
                stamp_nanos: f.stamp_nanos,
                camera: resized_camera(&f.camera, w, h),
                world_from_camera: f.world_from_camera,
            },
            depth: prediction.depth[v * w * h..(v + 1) * w * h].to_vec(),
            // At the sensor's resolution: the model's resampling spaces samples unevenly, which
            // a slanted surface turns into second differences that are not noise.
            depth_noise_at_1m: f
                .depth
                .as_ref()
                .and_then(|d| depth_noise::noise_at_1m([(d.metres.as_slice(), d.width as usize)])),
        })
        .collect()
}

#[cfg(test)]
mod tests;
