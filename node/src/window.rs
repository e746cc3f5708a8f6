//! The rolling window (DESIGN §5.0): keyframe selection, one reconstruction-model pass per window,
//! grouping of the embeddings, and the window instances and views that fusion takes.
//!
//! Frames become keyframes when the camera has moved at least `min_translation_m` or turned
//! `min_rotation_deg` since the last keyframe, or `max_interval_secs` passed. A window is the
//! newest keyframe and the `views − 1` keyframes before it (the most recent ones: on a moving robot
//! these are the most covisible; a covisibility ranking is future work).

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use crate::frame::{Keyframe, SyncedFrame, WindowInstance, WindowView};
use crate::group::semantics::{prototypes, LabelledView};
use crate::group::{group, GroupError, GroupingParams};
use crate::model::reconstruction::{lifted_pixels, resized_camera, ReconstructionModel, View};
use crate::model::semantic::{DenseFeatures, SemanticModel};
use crate::model::ModelError;
use crate::recon::gaussians::Gaussians;

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
}

impl Default for WindowSection {
    fn default() -> Self {
        Self {
            views: 4,
            min_translation_m: 0.2,
            min_rotation_deg: 15.0,
            max_interval_secs: 1.0,
            max_keyframes: 32,
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
            self.frames.push_back(frame.clone());
            self.fresh += 1;
            while self.frames.len() > p.max_keyframes.max(p.views) {
                self.frames.pop_front();
            }
        }
        keep
    }

    /// The next window once `views` new keyframes have arrived since the last one (windows do
    /// not overlap, so every keyframe is seen once at this pace).
    pub fn take_window(&mut self) -> Option<Vec<SyncedFrame>> {
        let views = self.params.views.clamp(2, 24);
        if self.fresh < views || self.frames.len() < views {
            return None;
        }
        self.fresh = 0;
        Some(
            self.frames
                .iter()
                .skip(self.frames.len() - views)
                .cloned()
                .collect(),
        )
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
    let views: Vec<View<'_>> = frames
        .iter()
        .map(|f| View {
            rgb: &f.rgb,
            depth: f.depth.as_ref(),
            camera: f.camera,
            world_from_camera: f.world_from_camera,
        })
        .collect();
    let prediction = model.predict(&views)?;
    let gaussians = model.to_gaussians(&prediction, &views)?;
    let grouped = group(
        &gaussians.embeddings,
        gaussians.embedding_dim.max(1),
        grouping,
    )?;
    let clusters = grouped.centroids.len();
    let mut per_instance: Vec<Gaussians> =
        (0..clusters).map(|_| Gaussians::with_dims(0, 0)).collect();
    let mut noise = 0;
    for (i, &label) in grouped.labels.iter().enumerate() {
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
    let (mut instance_prototypes, mut semantics_error) = (Vec::new(), None);
    if let Some(semantic) = semantic {
        let pixels = lifted_pixels(&prediction);
        if pixels.len() != grouped.labels.len() {
            semantics_error = Some(format!(
                "{} labels for {} lifted pixels",
                grouped.labels.len(),
                pixels.len()
            ));
        } else {
            let mut pixel_labels = vec![-1i32; prediction.views * w * h];
            for (&pixel, &label) in pixels.iter().zip(&grouped.labels) {
                pixel_labels[pixel] = label;
            }
            match instance_semantics(semantic, frames, &pixel_labels, (w, h), clusters) {
                Ok(found) => instance_prototypes = found,
                Err(e) => semantics_error = Some(e.to_string()),
            }
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
        })
        .collect();
    Ok(WindowOutput {
        instances,
        views: window_views,
        gaussians: gaussians.len(),
        noise,
        semantics_error,
    })
}

/// Prototypes of `clusters` instances from per-pixel labels at the model resolution (`size`,
/// view-major); each view's labels are sampled at its feature pixels' centres. An instance no
/// feature pixel sees gets an empty prototype.
fn instance_semantics(
    semantic: &mut SemanticModel,
    frames: &[SyncedFrame],
    pixel_labels: &[i32],
    (width, height): (usize, usize),
    clusters: usize,
) -> Result<Vec<Vec<f32>>, WindowError> {
    let features: Vec<DenseFeatures> = frames
        .iter()
        .map(|f| semantic.features(&f.rgb))
        .collect::<Result<_, _>>()?;
    let labels: Vec<Vec<i32>> = features
        .iter()
        .enumerate()
        .map(|(v, f)| {
            let view = &pixel_labels[v * width * height..(v + 1) * width * height];
            let mut out = Vec::with_capacity(f.width * f.height);
            for fy in 0..f.height {
                let y = (((fy as f64 + 0.5) * height as f64 / f.height as f64) as usize)
                    .min(height - 1);
                for fx in 0..f.width {
                    let x = (((fx as f64 + 0.5) * width as f64 / f.width as f64) as usize)
                        .min(width - 1);
                    out.push(view[y * width + x]);
                }
            }
            out
        })
        .collect();
    let views: Vec<LabelledView<'_>> = labels
        .iter()
        .zip(&features)
        .map(|(labels, f)| LabelledView {
            labels,
            features: &f.data,
        })
        .collect();
    let (found, counts) = prototypes(&views, semantic.channels(), clusters)
        .map_err(|e| ModelError::Input(e.to_string()))?;
    Ok(found
        .into_iter()
        .zip(counts)
        .map(|(p, count)| if count > 0 { p } else { Vec::new() })
        .collect())
}
