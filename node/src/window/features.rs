//! Semantic features of a window's views: computed ahead per keyframe and cached, each feature
//! pixel's best vocabulary phrase, and the instances' prototypes pooled from them (§5.5).

use std::collections::VecDeque;

use nalgebra::{DMatrix, DMatrixView};

use super::{WindowError, WindowSection};
use crate::frame::SyncedFrame;
use crate::group::semantics::{prototypes, LabelledView, Vocabulary};
use crate::model::semantic::{DenseFeatures, SemanticModel};
use crate::model::ModelError;
use crate::recon::metrics::sample_nearest;

/// Which keyframe a cached feature map belongs to: its camera and stamp.
pub(super) type FrameKey = (String, i64);

pub(super) fn frame_key(frame: &SyncedFrame) -> FrameKey {
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
    pub(super) capacity: usize,
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

    pub(super) fn contains(&self, key: &FrameKey) -> bool {
        self.entries.iter().any(|(k, _)| k == key)
    }

    pub(super) fn insert(&mut self, key: FrameKey, features: KeyframeFeatures) {
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

    pub(super) fn take(&mut self, key: &FrameKey) -> Option<KeyframeFeatures> {
        let at = self.entries.iter().position(|(k, _)| k == key)?;
        self.entries.remove(at).map(|(_, features)| features)
    }

    /// Drop what a window over `frames` made stale: its camera's entries up to its newest stamp
    /// (windows do not overlap, so no later window takes them).
    pub(super) fn prune_after(&mut self, frames: &[SyncedFrame]) {
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
    pub(super) classes: Option<Vec<Option<u32>>>,
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
pub(super) fn window_features(
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
pub(super) fn point_classes(
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
pub(super) fn instance_prototypes_of(
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
