//! The rolling window (DESIGN §5.0): keyframe selection, one reconstruction-model pass per window,
//! grouping of the embeddings, and the window instances and views that fusion takes.
//!
//! Frames become keyframes when the camera has moved at least `min_translation_m` or turned
//! `min_rotation_deg` since the last keyframe, or `max_interval_secs` passed. A window is the
//! newest keyframe and the `views − 1` keyframes before it (the most recent ones: on a moving robot
//! these are the most covisible; a covisibility ranking is future work).

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use crate::graph::{Keyframe, WindowInstance, WindowView};
use crate::group::{group, GroupError, GroupingParams};
use crate::ingest::SyncedFrame;
use crate::model::reconstruction::{resized_camera, ReconstructionModel, View};
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
}

/// Run the model on `frames`, group the embeddings, and split the Gaussians by instance.
/// Instances carry no semantic prototype until the semantic model lands (fusion then associates
/// by geometry alone).
pub fn window_pass(
    model: &mut ReconstructionModel,
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
    let instances = per_instance
        .into_iter()
        .filter(|g| !g.is_empty())
        .map(|g| WindowInstance {
            support: g.len(),
            gaussians: g,
            prototype: Vec::new(),
        })
        .collect();
    let (w, h) = (prediction.width, prediction.height);
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
    })
}
