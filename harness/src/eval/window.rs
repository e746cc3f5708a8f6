//! Per-window scores (ARCHITECTURE.md §6): windows of sim scenes no training saw through the node's window
//! pass, scored against the simulator's ground truth as the paper scores a feed-forward pass:
//! depth abs-rel and δ<1.25 of the model's own depth, instance ARI of the window's instances,
//! semantic pixel accuracy and mIoU of the semantic model in the source views, and in a novel view
//! between the first two (rendered from the window's instance Gaussians) PSNR, SSIM and the
//! semantic labels of the instances' prototypes. LPIPS needs pretrained network weights that
//! cannot be fetched here: it is not computed.

use groupforward_sim::library::classes;
use groupforward_sim::simulation::{SimView, Simulation};

use super::run::EvalError;
use groupforward::frame::{DepthImage, RgbImage, SyncedFrame};
use groupforward::group::semantics::{Vocabulary, OTHER_PHRASE};
use groupforward::model::reconstruction::{resize_rgb_planar, resized_camera};
use groupforward::recon::camera::Camera;
use groupforward::recon::gaussians::Gaussians;
use groupforward::recon::metrics::{
    adjusted_rand_index, depth_scores, object_coverage, psnr, sample_nearest, ssim, ObjectCoverage,
};
use groupforward::recon::raster::{render, render_labels, RasterSettings};
use groupforward::recon::Rigid;
use groupforward::window::WindowModels;

/// One window's scores (NaN where a score could not be computed, e.g. no semantic model).
#[derive(Debug, Clone, PartialEq)]
pub struct WindowScore {
    pub scene: String,
    /// The context views' frame indices, and the novel view's.
    pub frames: Vec<usize>,
    pub novel_frame: usize,
    pub instances: usize,
    pub depth_abs_rel: f64,
    pub depth_delta1: f64,
    pub ari: f64,
    /// Mean over the window's objects of their best instance IoU in pixels (mCov).
    pub object_coverage: f64,
    pub semantic_pixel_accuracy: f64,
    pub novel_psnr: f64,
    pub novel_ssim: f64,
    pub novel_semantic_pixel_accuracy: f64,
}

/// Objects with fewer pixels in a window (at the model resolution, all views) are not scored for
/// coverage: a sliver at the image border says nothing about grouping.
pub const COVERAGE_MIN_PIXELS: u64 = 200;

/// Labels (vocabulary phrase indices) predicted and true, pooled over windows for mIoU.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PooledLabels {
    pub predicted: Vec<u32>,
    pub truth: Vec<u32>,
}

impl PooledLabels {
    fn push(&mut self, predicted: u32, truth: u32) {
        self.predicted.push(predicted);
        self.truth.push(truth);
    }

    /// The share of the pixels pushed since `from` (one window's) whose label is right (NaN when
    /// none was).
    fn accuracy_from(&self, from: usize) -> f64 {
        let (predicted, truth) = (&self.predicted[from..], &self.truth[from..]);
        let hits = predicted.iter().zip(truth).filter(|(p, t)| p == t).count();
        hits as f64 / truth.len() as f64
    }
}

/// One object in one window, and where its pixels went.
#[derive(Debug, Clone, PartialEq)]
pub struct CoveredObject {
    pub scene: String,
    pub class: String,
    pub coverage: ObjectCoverage,
}

/// Every window of an evaluation, and the labels its semantic scores pool.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WindowEval {
    pub rows: Vec<WindowScore>,
    /// Where each object's pixels went, per window.
    pub objects: Vec<CoveredObject>,
    pub source_labels: PooledLabels,
    pub novel_labels: PooledLabels,
}

/// The frames of `windows` windows of `views` views spread over a trajectory of `frames` frames:
/// context views `step` frames apart, and the novel view halfway between the first two.
pub fn window_frames(frames: usize, windows: usize, views: usize) -> Vec<(Vec<usize>, usize)> {
    let (windows, views) = (windows.max(1), views.max(2));
    let step = (frames / (windows * views)).max(2);
    (0..windows)
        .map(|w| w * views * step)
        .filter(|start| start + (views - 1) * step < frames)
        .map(|start| {
            (
                (0..views).map(|k| start + k * step).collect(),
                start + step / 2,
            )
        })
        .collect()
}

/// A sim view as ingest would sync it (first camera; pinhole, as the benchmark's cameras are).
pub fn synced_frame(view: &SimView, stamp_nanos: i64) -> Result<SyncedFrame, EvalError> {
    let p = view.pinhole;
    let camera = Camera::pinhole(p.width, p.height, p.fx, p.fy, p.cx, p.cy)
        .map_err(|e| EvalError::Sim("camera".into(), e.to_string()))?;
    Ok(SyncedFrame {
        camera_name: "front".into(),
        stamp_nanos,
        frame_id: "camera_color_optical_frame".into(),
        rgb: RgbImage {
            width: p.width,
            height: p.height,
            data: view.sensor_rgb().to_vec(),
        },
        depth: Some(DepthImage {
            width: p.width,
            height: p.height,
            metres: view.sensor_depth().to_vec(),
        }),
        camera,
        world_from_camera: Rigid::new(view.rotation, view.position),
    })
}

/// The vocabulary index of each sim class id (0, walls and floor, and unknown names: `other`).
fn class_phrases(vocabulary: &Vocabulary) -> impl Fn(u16) -> u32 + '_ {
    let other = phrase_index(vocabulary, OTHER_PHRASE);
    let named: Vec<(u16, u32)> = classes()
        .iter()
        .map(|c| (c.id, phrase_index(vocabulary, c.name)))
        .collect();
    move |class| {
        named
            .iter()
            .find(|(id, _)| *id == class && class != 0)
            .map_or(other, |(_, phrase)| *phrase)
    }
}

/// The index of `phrase` in the vocabulary; past the end when absent (scored as `other`).
pub fn phrase_index(vocabulary: &Vocabulary, phrase: &str) -> u32 {
    vocabulary
        .phrases
        .iter()
        .position(|p| p == phrase)
        .unwrap_or(vocabulary.phrases.len()) as u32
}

fn best_phrase(vocabulary: &Vocabulary, feature: &[f32]) -> u32 {
    vocabulary
        .hypotheses(feature, 1)
        .first()
        .map_or(phrase_index(vocabulary, OTHER_PHRASE), |(phrase, _)| {
            phrase_index(vocabulary, phrase)
        })
}

/// Score `windows` windows of `views` views of one scene into `eval`.
pub fn score_scene(
    sim: &Simulation,
    scene: &str,
    models: &mut WindowModels,
    windows: usize,
    views: usize,
    eval: &mut WindowEval,
) -> Result<(), EvalError> {
    let sim_error = |e: String| EvalError::Sim(scene.to_owned(), e);
    for (context, novel) in window_frames(sim.frame_count(), windows, views) {
        let sim_frames: Vec<_> = context.iter().map(|&i| sim.frame(i)).collect();
        if sim_frames.iter().any(|f| f.views.is_empty()) {
            continue; // a dropped frame: the node would not have it either
        }
        let frames = sim_frames
            .iter()
            .map(|f| synced_frame(&f.views[0], (f.time_secs * 1e9) as i64))
            .collect::<Result<Vec<_>, _>>()?;
        let output = models.pass(&frames)?;
        let Some(first) = output.views.first() else {
            continue; // nothing lifted: no valid depth
        };
        let (w, h) = (
            first.keyframe.camera.width as usize,
            first.keyframe.camera.height as usize,
        );
        let truth_at = |v: &SimView| {
            let full = (v.truth.width as usize, v.truth.height as usize);
            (
                sample_nearest(&v.truth.depth, full, (w, h)),
                sample_nearest(&v.truth.instance, full, (w, h)),
                sample_nearest(&v.truth.class, full, (w, h)),
            )
        };
        let (mut true_depth, mut true_instances) = (Vec::new(), Vec::new());
        for f in &sim_frames {
            let (depth, instances, _) = truth_at(&f.views[0]);
            true_depth.extend(depth);
            true_instances.extend(instances.into_iter().map(u32::from));
        }
        let depth = depth_scores(&output.model_depth, &true_depth)
            .map_err(|e| sim_error(format!("depth: {e}")))?;
        // Noise is one more group: a window that leaves objects ungrouped pays for it.
        let predicted: Vec<u32> = output
            .pixel_instances
            .iter()
            .map(|&k| u32::try_from(k).unwrap_or(u32::MAX))
            .collect();
        let ari = adjusted_rand_index(&predicted, &true_instances)
            .map_err(|e| sim_error(format!("ARI: {e}")))?;
        let coverage = object_coverage(
            &predicted,
            &true_instances,
            u32::MAX,
            0,
            COVERAGE_MIN_PIXELS,
        )
        .map_err(|e| sim_error(format!("coverage: {e}")))?;
        let object_coverage_mean =
            coverage.iter().map(|c| c.best_iou).sum::<f64>() / coverage.len().max(1) as f64;
        let class_names = classes();
        for c in coverage {
            let class = sim
                .scene
                .objects
                .iter()
                .find(|o| u32::from(o.instance_id) == c.object)
                .and_then(|o| class_names.iter().find(|k| k.id == o.class_id))
                .map_or("object", |k| k.name);
            eval.objects.push(CoveredObject {
                scene: scene.to_owned(),
                class: class.to_owned(),
                coverage: c,
            });
        }

        let mut semantic_accuracy = f64::NAN;
        let mut novel_semantic_accuracy = f64::NAN;
        let source_from = eval.source_labels.truth.len();
        if let (Some(semantic), Some(vocabulary)) = (models.semantic.as_mut(), &models.vocabulary) {
            let phrase_of_class = class_phrases(vocabulary);
            for (frame, sim_frame) in frames.iter().zip(&sim_frames) {
                let features = semantic
                    .features(&frame.rgb)
                    .map_err(|e| sim_error(format!("semantic model: {e}")))?;
                let view = &sim_frame.views[0];
                let full = (view.truth.width as usize, view.truth.height as usize);
                let classes =
                    sample_nearest(&view.truth.class, full, (features.width, features.height));
                for (pixel, &class) in classes.iter().enumerate() {
                    eval.source_labels.push(
                        best_phrase(vocabulary, &features.at(pixel)),
                        phrase_of_class(class),
                    );
                }
            }
            semantic_accuracy = eval.source_labels.accuracy_from(source_from);
        }

        // The novel view, rendered from the window's instance Gaussians at the model resolution.
        let target = sim.frame(novel);
        let (mut novel_psnr, mut novel_ssim) = (f64::NAN, f64::NAN);
        if let (Some(view), false) = (target.views.first(), output.instances.is_empty()) {
            let frame = synced_frame(view, (target.time_secs * 1e9) as i64)?;
            let camera = resized_camera(&frame.camera, w, h);
            let camera_from_world = frame.world_from_camera.inverse();
            let mut all = Gaussians::with_dims(0, 0);
            let mut owner = Vec::new();
            for (k, instance) in output.instances.iter().enumerate() {
                all.extend(&instance.gaussians);
                owner.extend(std::iter::repeat_n(k as u32, instance.gaussians.len()));
            }
            let colours: Vec<f32> = all.colors.iter().flat_map(|c| c.to_array()).collect();
            let settings = RasterSettings::default();
            let rendered = render(&all, &colours, 3, &camera, &camera_from_world, &settings)
                .map_err(|e| sim_error(format!("novel view: {e}")))?;
            let truth_rgb = RgbImage {
                width: view.truth.width,
                height: view.truth.height,
                data: view.truth.rgb.clone(),
            };
            let planar = resize_rgb_planar(&truth_rgb, w, h);
            let plane = w * h;
            let interleaved: Vec<f32> = (0..plane)
                .flat_map(|i| (0..3).map(move |c| (i, c)))
                .map(|(i, c)| planar[c * plane + i])
                .collect();
            novel_psnr = psnr(&rendered.features, &interleaved, 1.0)
                .map_err(|e| sim_error(format!("PSNR: {e}")))?;
            novel_ssim = ssim(&rendered.features, &interleaved, w, h, 3, 1.0)
                .map_err(|e| sim_error(format!("SSIM: {e}")))?;
            if let Some(vocabulary) = &models.vocabulary {
                let phrase_of_class = class_phrases(vocabulary);
                let other = phrase_index(vocabulary, OTHER_PHRASE);
                let named: Vec<u32> = output
                    .instances
                    .iter()
                    .map(|i| {
                        if i.prototype.is_empty() {
                            other
                        } else {
                            best_phrase(vocabulary, &i.prototype)
                        }
                    })
                    .collect();
                let labels = render_labels(&all, &owner, &camera, &camera_from_world, &settings)
                    .map_err(|e| sim_error(format!("novel labels: {e}")))?;
                let (_, _, classes) = truth_at(view);
                let from = eval.novel_labels.truth.len();
                // Where no instance rendered, the map says nothing: scored as `other`.
                for (label, &class) in labels.labels.iter().zip(&classes) {
                    let predicted = label.map_or(other, |k| named[k as usize]);
                    eval.novel_labels.push(predicted, phrase_of_class(class));
                }
                novel_semantic_accuracy = eval.novel_labels.accuracy_from(from);
            }
        }
        eval.rows.push(WindowScore {
            scene: scene.to_owned(),
            frames: context,
            novel_frame: novel,
            instances: output.instances.len(),
            depth_abs_rel: depth.abs_rel,
            depth_delta1: depth.delta1,
            ari,
            object_coverage: object_coverage_mean,
            semantic_pixel_accuracy: semantic_accuracy,
            novel_psnr,
            novel_ssim,
            novel_semantic_pixel_accuracy: novel_semantic_accuracy,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_fit_the_trajectory_with_the_novel_view_between_the_first_two() {
        let windows = window_frames(40, 2, 4);
        assert_eq!(
            windows,
            vec![(vec![0, 5, 10, 15], 2), (vec![20, 25, 30, 35], 22)]
        );
        // A short trajectory gives the windows that fit, never a frame past its end.
        let short = window_frames(7, 3, 4);
        assert_eq!(short, vec![(vec![0, 2, 4, 6], 1)]);
        assert!(window_frames(5, 1, 4).is_empty());
    }
}
