//! The rolling window (DESIGN §5.0): keyframe selection, one reconstruction-model pass per window,
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

use std::collections::VecDeque;

use nalgebra::{DMatrix, DMatrixView};
use serde::{Deserialize, Serialize};

use crate::exposure::ExposureTracker;
use crate::frame::{Keyframe, SyncedFrame, WindowInstance, WindowView};
use crate::graph::amodal::largest_side;
use crate::graph::{FusionReport, GraphError, Kinds, SceneMap};
use crate::group::cleaning::{
    drop_other_objects, drop_support_bleed, floor_height, flying_pixels, split_components,
    CleaningParams,
};
use crate::group::semantics::{
    prototypes, KindMemo, LabelledView, SemanticsSection, Vocabulary, OTHER_PHRASE,
};
use crate::group::{group, GroupError, GroupingParams};
use crate::model::manifest::InputMode;
use crate::model::reconstruction::{
    lifted_pixels, resized_camera, use_sensor_depth, ReconstructionModel, View,
};
use crate::model::semantic::{DenseFeatures, SemanticModel};
use crate::model::text::TextEncoder;
use crate::model::{ModelError, ModelsSection};
use crate::recon::depth_noise;
use crate::recon::gaussians::Gaussians;
use crate::recon::median;
use crate::recon::metrics::sample_nearest;
use crate::timing::{Stage, StageTimes};

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
    pub min_translation_m: f64,
    pub min_rotation_deg: f64,
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
            min_translation_m: 0.2,
            min_rotation_deg: 15.0,
            max_interval_secs: 1.0,
            max_keyframes: 32,
            features_ahead: true,
            exposure_compensation: true,
            flush_after_secs: 1.0,
        }
    }
}

/// Keyframes of one camera.
#[derive(Debug, Default)]
pub struct Keyframes {
    pub params: WindowSection,
    frames: VecDeque<SyncedFrame>,
    /// Keyframes added since the last window was taken.
    fresh: usize,
    exposure: ExposureTracker,
    /// When the last frame was offered (wall clock): how long the stream has been quiet.
    last_offer: Option<std::time::Instant>,
}

impl Keyframes {
    pub fn new(params: WindowSection) -> Self {
        Self {
            params,
            ..Self::default()
        }
    }

    /// Keep `frame` if it is a keyframe; returns whether it was.
    pub fn offer(&mut self, frame: &SyncedFrame) -> bool {
        self.last_offer = Some(std::time::Instant::now());
        let p = &self.params;
        let keep = match self.frames.back() {
            None => true,
            Some(last) => {
                let moved = (frame.world_from_camera.translation
                    - last.world_from_camera.translation)
                    .length();
                let turned = frame
                    .world_from_camera
                    .rotation
                    .angle_between(last.world_from_camera.rotation)
                    .to_degrees();
                let waited = (frame.stamp_nanos - last.stamp_nanos) as f64 / 1e9;
                moved >= p.min_translation_m
                    || turned >= p.min_rotation_deg
                    || waited >= p.max_interval_secs
            }
        };
        if keep {
            let mut kept = frame.clone();
            if p.exposure_compensation {
                self.exposure.compensate(&mut kept, self.frames.back());
            }
            self.frames.push_back(kept);
            self.fresh += 1;
            while self.frames.len() > p.max_keyframes.max(p.views) {
                self.frames.pop_front();
            }
        }
        keep
    }

    /// The newest keyframe as kept (exposure compensated).
    pub fn newest(&self) -> Option<&SyncedFrame> {
        self.frames.back()
    }

    /// The next window once `views` new keyframes have arrived since the last one (windows do
    /// not overlap, so every keyframe is seen once at this pace).
    pub fn take_window(&mut self) -> Option<Vec<SyncedFrame>> {
        let views = self.params.views.clamp(2, 24);
        if self.fresh < views || self.frames.len() < views {
            return None;
        }
        Some(self.newest_window(views))
    }

    /// The window of the keyframes still waiting for one, whatever their number: the newest
    /// `views` keyframes (some already in the previous window). `None` when none waits or fewer
    /// than `views` keyframes were ever kept (a model pass takes exactly `views`).
    pub fn take_pending_window(&mut self) -> Option<Vec<SyncedFrame>> {
        let views = self.params.views.clamp(2, 24);
        if self.fresh == 0 || self.frames.len() < views {
            return None;
        }
        Some(self.newest_window(views))
    }

    /// [`Self::take_pending_window`] once no frame was offered for `flush_after_secs` before
    /// `now` (never when that is 0 or less).
    pub fn take_quiet_window(&mut self, now: std::time::Instant) -> Option<Vec<SyncedFrame>> {
        let after = self.params.flush_after_secs;
        let quiet = self
            .last_offer
            .is_some_and(|last| now.saturating_duration_since(last).as_secs_f64() >= after);
        if after > 0.0 && quiet {
            self.take_pending_window()
        } else {
            None
        }
    }

    fn newest_window(&mut self, views: usize) -> Vec<SyncedFrame> {
        self.fresh = 0;
        self.frames
            .iter()
            .skip(self.frames.len() - views)
            .cloned()
            .collect()
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

/// Which keyframe a cached feature map belongs to: its camera and stamp.
type FrameKey = (String, i64);

fn frame_key(frame: &SyncedFrame) -> FrameKey {
    (frame.camera_name.clone(), frame.stamp_nanos)
}

/// Semantic features of keyframes, computed when each keyframe arrives (DESIGN §7: once per
/// keyframe), waiting for the window that pools them. A window takes its views' features out, so
/// at most the keyframes of the next window wait here; entries of windows that were dropped are
/// pruned when a later window of the same camera runs, and the capacity bounds the rest (each
/// entry is a full feature map: 4.7 MB for the shipped semantic model).
#[derive(Debug)]
pub struct FeatureCache {
    entries: VecDeque<(FrameKey, KeyframeFeatures)>,
    capacity: usize,
}

impl Default for FeatureCache {
    fn default() -> Self {
        Self::with_capacity(WindowSection::default().views)
    }
}

impl FeatureCache {
    pub fn with_capacity(capacity: usize) -> Self {
        Self {
            entries: VecDeque::new(),
            capacity,
        }
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    fn contains(&self, key: &FrameKey) -> bool {
        self.entries.iter().any(|(k, _)| k == key)
    }

    fn insert(&mut self, key: FrameKey, features: KeyframeFeatures) {
        if self.capacity == 0 || self.contains(&key) {
            return;
        }
        self.entries.push_back((key, features));
        while self.entries.len() > self.capacity {
            self.entries.pop_front();
        }
    }

    /// Compute `frame`'s features with `semantic` (and, with a `vocabulary`, their classes) and
    /// keep them for its window; the time it took, `None` when they are cached already or the
    /// model failed (the window then computes them and reports the failure).
    pub fn prepare(
        &mut self,
        semantic: &mut SemanticModel,
        vocabulary: Option<&Vocabulary>,
        frame: &SyncedFrame,
    ) -> Option<std::time::Duration> {
        let key = frame_key(frame);
        if self.contains(&key) {
            return None;
        }
        let started = std::time::Instant::now();
        let features = semantic.features(&frame.rgb).ok()?;
        self.insert(key, KeyframeFeatures::named(features, vocabulary));
        Some(started.elapsed())
    }

    fn take(&mut self, key: &FrameKey) -> Option<KeyframeFeatures> {
        let at = self.entries.iter().position(|(k, _)| k == key)?;
        self.entries.remove(at).map(|(_, features)| features)
    }

    /// Drop what a window over `frames` made stale: its camera's entries up to its newest stamp
    /// (windows do not overlap, so no later window takes them).
    fn prune_after(&mut self, frames: &[SyncedFrame]) {
        for frame in frames {
            self.entries.retain(|((camera, stamp), _)| {
                *camera != frame.camera_name || *stamp > frame.stamp_nanos
            });
        }
    }
}

/// One keyframe's semantic features and, once a vocabulary named them, the class of each feature
/// pixel ([`feature_classes`]): both depend on the keyframe alone, so both are computed when it
/// arrives.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeFeatures {
    pub features: DenseFeatures,
    classes: Option<Vec<Option<u32>>>,
}

impl KeyframeFeatures {
    /// `features`, with their classes when a `vocabulary` is given.
    pub fn named(features: DenseFeatures, vocabulary: Option<&Vocabulary>) -> Self {
        let classes = vocabulary.map(|v| feature_classes(&features, v));
        Self { features, classes }
    }
}

/// The semantic features of every view of a window: cached ones taken out of `cache`, the rest
/// computed now (classes too, with a `vocabulary`). Returns how many were cached.
fn window_features(
    semantic: &mut SemanticModel,
    cache: &mut FeatureCache,
    vocabulary: Option<&Vocabulary>,
    frames: &[SyncedFrame],
) -> (Result<Vec<KeyframeFeatures>, ModelError>, usize) {
    let mut cached = 0;
    let features = frames
        .iter()
        .map(|f| match cache.take(&frame_key(f)) {
            Some(mut ahead) => {
                cached += 1;
                if let (None, Some(v)) = (&ahead.classes, vocabulary) {
                    ahead.classes = Some(feature_classes(&ahead.features, v));
                }
                Ok(ahead)
            }
            None => semantic
                .features(&f.rgb)
                .map(|features| KeyframeFeatures::named(features, vocabulary)),
        })
        .collect();
    cache.prune_after(frames);
    (features, cached)
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
    // The semantic features the window still lacks (the newest keyframe's: it completes the
    // window, so it was not computed ahead) are computed beside the reconstruction model's pass,
    // whose two threads leave a core idle part of the time.
    let (prediction, features) = std::thread::scope(|scope| {
        let features = semantic.map(|(semantic, cache)| {
            scope.spawn(move || window_features(semantic, cache, vocabulary, frames))
        });
        let prediction = times.time(Stage::Model, || model.predict(&views));
        let features = features.map(|handle| {
            handle.join().unwrap_or_else(|_| {
                let lost = ModelError::Input("the semantic features' thread panicked".into());
                (Err(lost), 0)
            })
        });
        (prediction, features)
    });
    let mut prediction = prediction?;
    let model_depth = prediction.depth.clone();
    let lifted = times.time(Stage::Lift, || {
        // RGB-D: geometry from the depth camera (the eval's recall at IoU 0.5 doubles against
        // the model's own depth), instances from the model.
        let from_neighbours = if model.mode() == InputMode::Rgbd {
            use_sensor_depth(&mut prediction, &views)
        } else {
            0
        };
        let invalid = prediction
            .depth
            .iter()
            .filter(|d| !(d.is_finite() && **d > 0.0))
            .count();
        model
            .to_gaussians(&prediction, &views)
            .map(|g| (g, invalid, from_neighbours))
    });
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
    let grouped = times.time(Stage::Group, || {
        group(
            &gaussians.embeddings,
            gaussians.embedding_dim.max(1),
            grouping,
        )
    })?;
    let clean_started = std::time::Instant::now();
    let (w, h) = (prediction.width, prediction.height);
    let pixels = lifted_pixels(&prediction);
    // Map hygiene: no flying pixels or transparent Gaussians in objects, and a cluster that falls
    // apart in space becomes its parts.
    let cleaning = CleaningParams::default();
    let flying = flying_pixels(&prediction.depth, w, h, cleaning.flying_ratio);
    let mut labels = grouped.labels;
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
    times.0.push((Stage::Clean, clean_started.elapsed()));
    let semantics_started = std::time::Instant::now();
    let (mut instance_prototypes, mut semantics_error) = (Vec::new(), None);
    let mut features_cached = 0;
    if let Some((features, cached)) = features {
        features_cached = cached;
        match features {
            Err(e) => semantics_error = Some(e.to_string()),
            Ok(features) => {
                let size = (w, h);
                // Instances of one kind of thing: what the semantic model calls another object
                // leaves an object's instance (a chair's legs grouped with the table they touch).
                if let Some(vocabulary) = vocabulary {
                    let classes = point_classes(&features, &pixels, size);
                    let other = vocabulary
                        .phrases
                        .iter()
                        .position(|p| p == OTHER_PHRASE)
                        .unwrap_or(vocabulary.phrases.len()) as u32;
                    let before = labels.clone();
                    drop_other_objects(&mut labels, &classes, clusters, other);
                    mark_dropped(&before, &labels, &mut why, Unassigned::OtherObject);
                }
                match instance_prototypes_of(&features, &pixels, &labels, size, clusters) {
                    Ok(found) => instance_prototypes = found,
                    Err(e) => semantics_error = Some(e.to_string()),
                }
            }
        }
    }
    times
        .0
        .push((Stage::Semantics, semantics_started.elapsed()));
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
    let (w, h) = (prediction.width, prediction.height);
    // Clusters left empty are dropped: instance indices count the kept ones.
    let mut instance_of_cluster = vec![-1i32; per_instance.len()];
    let mut kept = 0;
    for (k, g) in per_instance.iter().enumerate() {
        if !g.is_empty() {
            instance_of_cluster[k] = kept;
            kept += 1;
        }
    }
    let mut pixel_instances = vec![Unassigned::NotLifted as i32; prediction.depth.len()];
    for ((&pixel, &label), &reason) in pixels.iter().zip(&labels).zip(&why) {
        if let Some(slot) = pixel_instances.get_mut(pixel) {
            *slot = match usize::try_from(label) {
                Ok(k) => instance_of_cluster[k],
                Err(_) => reason as i32,
            };
        }
    }
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
    let window_views = frames
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
        .collect();
    Ok(WindowOutput {
        instances,
        views: window_views,
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

/// The best vocabulary phrase by cosine of each pixel of `f`; `None` where no phrase of its width
/// scores finite. The scores of every pixel against every phrase are one GEMM of the
/// channel-planar features (pixels × channels) with the unit phrase directions (channels ×
/// phrases): a dot product per pixel and phrase took 5 ms a view on 2 cores.
pub fn feature_classes(f: &DenseFeatures, vocabulary: &Vocabulary) -> Vec<Option<u32>> {
    let plane = f.width * f.height;
    let usable: Vec<(u32, &Vec<f32>, f32)> = vocabulary
        .embeddings
        .iter()
        .enumerate()
        .map(|(k, e)| (k as u32, e, e.iter().map(|v| v * v).sum::<f32>().sqrt()))
        .filter(|(_, e, norm)| e.len() == f.channels && *norm > 0.0 && norm.is_finite())
        .collect();
    if usable.is_empty() || plane == 0 || f.data.len() < f.channels * plane {
        return vec![None; plane];
    }
    let directions = DMatrix::from_fn(f.channels, usable.len(), |c, j| {
        usable[j].1[c] / usable[j].2
    });
    let pixels_by_channel =
        DMatrixView::from_slice(&f.data[..f.channels * plane], plane, f.channels);
    let scores = pixels_by_channel * directions;
    (0..plane)
        .map(|p| {
            let mut best: Option<(u32, f32)> = None;
            for (j, &(k, _, _)) in usable.iter().enumerate() {
                let score = scores[(p, j)];
                if score.is_finite() && best.is_none_or(|(_, s)| score > s) {
                    best = Some((k, score));
                }
            }
            best.map(|(k, _)| k)
        })
        .collect()
}

/// The semantic class of each lifted point (its view's [`feature_classes`]), read at the feature
/// pixel its model pixel falls in (`pixels`: each point's model pixel, view-major, of `size`
/// model images); `None` where no feature or no class is there.
fn point_classes(
    views: &[KeyframeFeatures],
    pixels: &[usize],
    (width, height): (usize, usize),
) -> Vec<Option<u32>> {
    let plane = (width * height).max(1);
    pixels
        .iter()
        .map(|&pixel| {
            let (view, at) = (pixel / plane, pixel % plane);
            let view = views.get(view)?;
            let (f, of_view) = (&view.features, view.classes.as_ref()?);
            let (x, y) = (at % width.max(1), at / width.max(1));
            let (fx, fy) = (x * f.width / width.max(1), y * f.height / height.max(1));
            of_view.get(fy * f.width + fx).copied().flatten()
        })
        .collect()
}

/// Prototypes of `clusters` instances (§5.5): the masked mean of the views' semantic features,
/// each view's labels sampled at its feature pixels' centres from the Gaussians' labels (`pixels`:
/// each Gaussian's model pixel, view-major). An instance no feature pixel sees gets an empty
/// prototype.
fn instance_prototypes_of(
    features: &[KeyframeFeatures],
    pixels: &[usize],
    labels: &[i32],
    (width, height): (usize, usize),
    clusters: usize,
) -> Result<Vec<Vec<f32>>, WindowError> {
    if pixels.len() != labels.len() {
        return Err(ModelError::Input(format!(
            "{} labels for {} lifted pixels",
            labels.len(),
            pixels.len()
        ))
        .into());
    }
    let mut pixel_labels = vec![-1i32; features.len() * width * height];
    for (&pixel, &label) in pixels.iter().zip(labels) {
        if let Some(slot) = pixel_labels.get_mut(pixel) {
            *slot = label;
        }
    }
    let sampled: Vec<Vec<i32>> = features
        .iter()
        .enumerate()
        .map(|(v, KeyframeFeatures { features: f, .. })| {
            let view = &pixel_labels[v * width * height..(v + 1) * width * height];
            sample_nearest(view, (width, height), (f.width, f.height))
        })
        .collect();
    let views: Vec<LabelledView<'_>> = sampled
        .iter()
        .zip(features)
        .map(|(labels, f)| LabelledView {
            labels,
            features: &f.features.data,
        })
        .collect();
    let channels = features.first().map_or(0, |f| f.features.channels);
    let (found, counts) =
        prototypes(&views, channels, clusters).map_err(|e| ModelError::Input(e.to_string()))?;
    Ok(found
        .into_iter()
        .zip(counts)
        .map(|(p, count)| if count > 0 { p } else { Vec::new() })
        .collect())
}

/// What a window pass runs on: the reconstruction model, and (optional) the semantic model with
/// the vocabulary embedded by the text encoder that names instances.
#[derive(Debug)]
pub struct WindowModels {
    pub reconstruction: ReconstructionModel,
    pub semantic: Option<SemanticModel>,
    pub vocabulary: Option<Vocabulary>,
    /// The text encoder that embedded the vocabulary, kept for referring queries' phrases.
    pub text_encoder: Option<TextEncoder>,
    pub grouping: GroupingParams,
    /// Semantic features of keyframes computed on arrival ([`WindowModels::prepare`]).
    pub features: FeatureCache,
}

impl WindowModels {
    /// Load the models `models` names. The reconstruction model is required; the semantic model
    /// and the text encoder may be missing or broken: instances are then unnamed (logged once).
    pub fn load(models: &ModelsSection, semantics: &SemanticsSection) -> Result<Self, ModelError> {
        let options = models.session_options();
        crate::model::init_runtime(models.onnxruntime.as_deref())?;
        let manifest = models
            .reconstruction
            .as_ref()
            .ok_or_else(|| ModelError::Input("no reconstruction model configured".into()))?;
        let reconstruction = ReconstructionModel::load(manifest, &options)?;
        tracing::info!("reconstruction model {} loaded", manifest.display());
        let semantic = match models.semantic.as_ref() {
            None => None,
            Some(path) if !path.exists() => {
                tracing::warn!(
                    "no semantic model at {}: instances will be unnamed",
                    path.display()
                );
                None
            }
            Some(path) => match SemanticModel::load(path, &options) {
                Ok(model) => {
                    tracing::info!("semantic model {} loaded", path.display());
                    Some(model)
                }
                Err(e) => {
                    tracing::error!("semantic model unavailable: {e}; instances will be unnamed");
                    None
                }
            },
        };
        let mut text_encoder = None;
        let vocabulary = semantic.as_ref().and_then(|_| {
            let embedded =
                TextEncoder::load(&models.text_encoder, &options).and_then(|mut encoder| {
                    let embeddings = semantics
                        .vocabulary
                        .iter()
                        .map(|phrase| encoder.embed(phrase))
                        .collect::<crate::model::Result<Vec<_>>>()?;
                    text_encoder = Some(encoder);
                    Ok(Vocabulary {
                        phrases: semantics.vocabulary.clone(),
                        embeddings,
                        temperature: semantics.temperature,
                    })
                });
            embedded
                .map_err(|e| {
                    tracing::error!("text encoder unavailable: {e}; instances will be unnamed")
                })
                .ok()
        });
        Ok(Self {
            reconstruction,
            semantic,
            vocabulary,
            text_encoder,
            grouping: GroupingParams::default(),
            features: FeatureCache::default(),
        })
    }

    /// Keep computed-ahead features for windows of `views` views (2–24, as windows take them).
    pub fn set_views(&mut self, views: usize) {
        let views = views.clamp(2, 24);
        if self.features.capacity != views {
            self.features = FeatureCache::with_capacity(views);
        }
    }

    /// Compute a keyframe's semantic features ahead of its window (when the worker would
    /// otherwise wait), so the window pass only pools them. Returns the time it took, `None` when
    /// there is no semantic model, the features are cached already, or the model failed (the
    /// window then computes them, and reports the failure).
    pub fn prepare(&mut self, frame: &SyncedFrame) -> Option<std::time::Duration> {
        self.features
            .prepare(self.semantic.as_mut()?, self.vocabulary.as_ref(), frame)
    }

    /// Fuse a window's instances into `map`; with a vocabulary, fragments of one object (touching,
    /// alike, named alike) fold together afterwards ([`SceneMap::fold_fragments`]).
    pub fn fuse(
        &self,
        map: &mut SceneMap,
        instances: Vec<WindowInstance>,
        views: &[WindowView],
        stamp_nanos: i64,
    ) -> Result<FusionReport, GraphError> {
        match &self.vocabulary {
            Some(v) => map.fuse_named(instances, views, stamp_nanos, KindMemo::new(v)),
            None => map.fuse(instances, views, stamp_nanos),
        }
    }

    /// One window pass over `frames`.
    pub fn pass(&mut self, frames: &[SyncedFrame]) -> Result<WindowOutput, WindowError> {
        pass_with_cache(
            &mut self.reconstruction,
            self.semantic.as_mut().map(|m| (m, &mut self.features)),
            self.vocabulary.as_ref(),
            frames,
            &self.grouping,
        )
    }
}

/// The vocabulary as fusion asks it: kinds by best name, sizes by [`largest_side`].
impl Kinds for KindMemo<'_> {
    fn same_kind(&self, a: &[f32], b: &[f32]) -> bool {
        KindMemo::same_kind(self, a, b)
    }

    fn largest_side(&self, prototype: &[f32]) -> Option<f64> {
        self.best_phrase(prototype)
            .and_then(|name| largest_side(&name))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_dropped_point_keeps_the_first_stage_that_dropped_it() {
        let mut why = vec![Unassigned::Noise; 4];
        // HDBSCAN left point 0 as noise; the edge stage dropped point 1, the speck stage 2.
        mark_dropped(&[-1, 0, 0, 1], &[-1, -1, 0, 1], &mut why, Unassigned::Edge);
        mark_dropped(
            &[-1, -1, 0, 1],
            &[-1, -1, -1, 1],
            &mut why,
            Unassigned::Speck,
        );
        assert_eq!(
            why[..3],
            [Unassigned::Noise, Unassigned::Edge, Unassigned::Speck]
        );
        // The codes are negative, distinct, and read back; an instance index is no reason.
        for reason in Unassigned::ALL {
            assert!((reason as i32) < 0);
            assert_eq!(Unassigned::of_code(reason as i32), Some(reason));
        }
        assert_eq!(Unassigned::of_code(0), None);
        assert_eq!(Unassigned::of_code(-7), None);
    }

    /// A frame `x` metres along the track at `secs` (a keyframe every 0.2 m).
    fn frame_at(x: f64, secs: f64) -> SyncedFrame {
        SyncedFrame {
            camera_name: "front".into(),
            stamp_nanos: (secs * 1e9) as i64,
            frame_id: "camera".into(),
            rgb: crate::frame::RgbImage {
                width: 0,
                height: 0,
                data: Vec::new(),
            },
            depth: None,
            camera: crate::recon::camera::Camera::from_fov(4, 4, 1.0)
                .unwrap_or_else(|e| panic!("{e}")),
            world_from_camera: crate::recon::Rigid::new(
                glam::DQuat::IDENTITY,
                glam::DVec3::new(x, 0.0, 0.0),
            ),
        }
    }

    fn stamps(window: &[SyncedFrame]) -> Vec<i64> {
        window.iter().map(|f| f.stamp_nanos / 100_000_000).collect()
    }

    #[test]
    fn keyframes_short_of_a_window_when_the_stream_ends_form_one_with_the_newest() {
        let mut store = Keyframes::new(WindowSection {
            views: 4,
            exposure_compensation: false,
            ..WindowSection::default()
        });
        // Three keyframes: fewer than a model pass takes, so nothing even at the end.
        for k in 0..3 {
            assert!(store.offer(&frame_at(0.3 * f64::from(k), 0.1 * f64::from(k))));
        }
        assert_eq!(store.take_pending_window(), None);
        // The fourth completes a window; two more wait for the next one.
        assert!(store.offer(&frame_at(0.9, 0.3)));
        assert_eq!(
            store.take_window().as_deref().map(stamps),
            Some(vec![0, 1, 2, 3])
        );
        assert_eq!(store.take_pending_window(), None, "nothing waits");
        for k in 4..6 {
            assert!(store.offer(&frame_at(0.3 * f64::from(k), 0.1 * f64::from(k))));
        }
        assert_eq!(store.take_window(), None);
        assert_eq!(
            store.take_pending_window().as_deref().map(stamps),
            Some(vec![2, 3, 4, 5]),
            "the newest four, two of them already in the last window"
        );
        assert_eq!(store.take_pending_window(), None, "taken once");
    }

    #[test]
    fn a_quiet_stream_flushes_its_waiting_keyframes_only_after_the_configured_time() {
        let started = std::time::Instant::now();
        for (flush_after_secs, expected) in [(1.0, true), (0.0, false)] {
            let mut store = Keyframes::new(WindowSection {
                views: 2,
                exposure_compensation: false,
                flush_after_secs,
                ..WindowSection::default()
            });
            for k in 0..3 {
                store.offer(&frame_at(0.3 * f64::from(k), 0.1 * f64::from(k)));
            }
            assert!(store.take_window().is_some());
            store.offer(&frame_at(0.9, 0.3));
            assert_eq!(store.take_quiet_window(started), None, "not quiet yet");
            let later = std::time::Instant::now() + std::time::Duration::from_secs(2);
            assert_eq!(
                store.take_quiet_window(later).is_some(),
                expected,
                "flush_after_secs {flush_after_secs}"
            );
        }
    }

    fn features(value: f32) -> KeyframeFeatures {
        let dense = DenseFeatures {
            width: 1,
            height: 1,
            channels: 1,
            data: vec![value],
        };
        KeyframeFeatures::named(dense, None)
    }

    fn key(camera: &str, stamp: i64) -> FrameKey {
        (camera.to_owned(), stamp)
    }

    #[test]
    fn each_point_takes_the_class_of_the_feature_pixel_it_falls_in() {
        // One view of 4 x 2 model pixels, features of 2 x 1 pixels in 2 channels: the left
        // feature pixel points at "chair", the right one at "table".
        let features = DenseFeatures {
            width: 2,
            height: 1,
            channels: 2,
            data: vec![1.0, 0.1, 0.1, 1.0],
        };
        let vocabulary = Vocabulary {
            phrases: vec!["chair".into(), "table".into()],
            embeddings: vec![vec![1.0, 0.0], vec![0.0, 1.0]],
            temperature: 0.05,
        };
        let named = KeyframeFeatures::named(features.clone(), Some(&vocabulary));
        let classes = point_classes(&[named], &[0, 1, 2, 7, 99], (4, 2));
        assert_eq!(classes, [Some(0), Some(0), Some(1), Some(1), None]);
        // Features no vocabulary named have no classes.
        let unnamed = KeyframeFeatures::named(features, None);
        assert_eq!(point_classes(&[unnamed], &[0, 7], (4, 2)), [None, None]);
    }

    #[test]
    fn feature_classes_are_each_pixels_best_phrase_by_cosine() {
        // 5 x 3 pixels of 6 channels against phrases of every length and norm: the GEMM's
        // classes equal a plain per-pixel cosine argmax; a phrase of the wrong width or of zero
        // length is never chosen, and a pixel with a NaN feature has no class.
        let (width, height, channels) = (5, 3, 6);
        let plane = width * height;
        let mut data: Vec<f32> = (0..channels * plane)
            .map(|i| ((i * 7919) % 113) as f32 / 56.0 - 1.0)
            .collect();
        data[2 * plane + 4] = f32::NAN;
        let f = DenseFeatures {
            width,
            height,
            channels,
            data,
        };
        let embeddings: Vec<Vec<f32>> = vec![
            vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            vec![0.2, -1.0, 0.5, 0.0, 3.0, 0.1],
            vec![5.0, 5.0],
            vec![0.0, 2.0, 0.0, -1.0, 0.0, 0.7],
        ];
        let vocabulary = Vocabulary {
            phrases: (0..embeddings.len()).map(|k| format!("p{k}")).collect(),
            embeddings: embeddings.clone(),
            temperature: 0.05,
        };
        let classes = feature_classes(&f, &vocabulary);
        assert_eq!(classes.len(), plane);
        for (p, class) in classes.iter().enumerate() {
            let pixel: Vec<f32> = (0..channels).map(|c| f.data[c * plane + p]).collect();
            let mut best: Option<(u32, f32)> = None;
            for (k, e) in embeddings.iter().enumerate() {
                let norm = e.iter().map(|v| v * v).sum::<f32>().sqrt();
                if e.len() != channels || norm == 0.0 {
                    continue;
                }
                let cosine = e.iter().zip(&pixel).map(|(a, b)| a * b).sum::<f32>() / norm;
                if cosine.is_finite() && best.is_none_or(|(_, s)| cosine > s) {
                    best = Some((k as u32, cosine));
                }
            }
            assert_eq!(*class, best.map(|(k, _)| k), "pixel {p}");
        }
        assert_eq!(classes[4], None, "the NaN pixel");
        assert!(classes.iter().flatten().all(|&k| k != 1 && k != 3));
    }

    #[test]
    fn the_feature_cache_keeps_the_newest_entries_and_hands_each_out_once() {
        let mut cache = FeatureCache::with_capacity(2);
        cache.insert(key("front", 1), features(1.0));
        cache.insert(key("front", 2), features(2.0));
        // A second insert of a key keeps the first features.
        cache.insert(key("front", 2), features(9.0));
        cache.insert(key("front", 3), features(3.0));
        assert_eq!(cache.len(), 2, "capacity bounds the entries");
        assert!(cache.take(&key("front", 1)).is_none(), "the oldest left");
        assert_eq!(cache.take(&key("front", 2)), Some(features(2.0)));
        assert!(cache.take(&key("front", 2)).is_none(), "handed out once");
        assert!(
            cache.take(&key("rear", 3)).is_none(),
            "another camera's stamp"
        );
        assert_eq!(cache.take(&key("front", 3)), Some(features(3.0)));
        assert!(cache.is_empty());
        let mut off = FeatureCache::with_capacity(0);
        off.insert(key("front", 1), features(1.0));
        assert!(off.is_empty());
    }
}
