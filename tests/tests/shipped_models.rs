//! The shipped models on rooms they never trained on (the sim's `val` split, rendered at the node's
//! usual 320×240, not the 128×96 of training): the semantic model names pixels through the text
//! encoder as the ground truth does, a window pass gives instances finite prototypes that name them,
//! and the RGB reconstruction model builds instances without sensor depth (from colour and the views'
//! TF poses) with plausible depth.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use std::path::Path;

use groupforward::frame::{RgbImage, SyncedFrame};
use groupforward::group::semantics::Vocabulary;
use groupforward::group::semantics::{default_vocabulary, OTHER_PHRASE};
use groupforward::group::votes::split_by_votes;
use groupforward::group::{group, GroupingParams};
use groupforward::model::manifest::InputMode;
use groupforward::model::reconstruction::{
    lifted_pixels, use_sensor_depth, ReconstructionModel, View, MODEL_DEPTH_AGREEMENT,
};
use groupforward::model::semantic::SemanticModel;
use groupforward::model::text::TextEncoder;
use groupforward::model::{init_runtime, SessionOptions};
use groupforward::recon::metrics::adjusted_rand_index;
use groupforward::recon::Rigid;
use groupforward::window::{pass_with_cache, window_pass, FeatureCache};
use groupforward_harness::eval::window::synced_frame;
use groupforward_sim::effects::Preset;
use groupforward_sim::procedural::{generate, Split};
use groupforward_sim::simulation::Simulation;

fn models() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models")
}

fn vocabulary() -> Vocabulary {
    let mut encoder = TextEncoder::load(
        &models().join("all-MiniLM-L6-v2.toml"),
        &SessionOptions::default(),
    )
    .unwrap();
    let phrases = default_vocabulary();
    Vocabulary {
        embeddings: phrases.iter().map(|p| encoder.embed(p).unwrap()).collect(),
        phrases,
        temperature: 0.05,
        priors: groupforward::group::semantics::ClassPriors::builtin(),
    }
}

/// The vocabulary phrase of a ground-truth class id (0: walls and floor = `other`).
fn phrase_of(class_id: u16) -> &'static str {
    if class_id == 0 {
        return OTHER_PHRASE;
    }
    groupforward_sim::library::classes()
        .iter()
        .find(|c| c.id == class_id)
        .map(|c| c.name)
        .unwrap()
}

#[test]
fn the_semantic_model_names_pixels_of_unseen_val_rooms() {
    init_runtime(None).unwrap_or_else(|e| panic!("{e}"));
    let mut model = SemanticModel::load(
        &models().join("semantic-mini.toml"),
        &SessionOptions::default(),
    )
    .unwrap();
    let vocabulary = vocabulary();
    let (mut object_hits, mut object_total, mut hits, mut total) = (0usize, 0usize, 0usize, 0usize);
    for index in 0..4 {
        let sim = Simulation::new(generate(Split::Val, index).unwrap()).unwrap();
        for frame_index in [0, sim.frame_count() / 2] {
            let frame = sim.frame(frame_index);
            let view = &frame.views[0];
            let (w, h) = (view.truth.width as usize, view.truth.height as usize);
            let image = RgbImage {
                width: w as u32,
                height: h as u32,
                data: view.sensor_rgb().to_vec(),
            };
            let features = model.features(&image).unwrap();
            assert!(features.data.iter().all(|v| v.is_finite()));
            for fy in 0..features.height {
                let y = ((fy as f64 + 0.5) * h as f64 / features.height as f64) as usize;
                for fx in 0..features.width {
                    let x = ((fx as f64 + 0.5) * w as f64 / features.width as f64) as usize;
                    let pixel = fy * features.width + fx;
                    let named = vocabulary.hypotheses(&features.at(pixel), 1);
                    let truth = phrase_of(view.truth.class[y * w + x]);
                    let hit = named[0].0 == truth;
                    hits += usize::from(hit);
                    total += 1;
                    if truth != OTHER_PHRASE {
                        object_hits += usize::from(hit);
                        object_total += 1;
                    }
                }
            }
        }
    }
    // Measured with the shipped model: 0.840 and 0.765. Naming every pixel `other` would score 0 on
    // object pixels; chance over the 17 phrases is 0.06.
    const PIXEL_ACCURACY: f64 = 0.75;
    const OBJECT_PIXEL_ACCURACY: f64 = 0.6;
    let accuracy = hits as f64 / total as f64;
    let object_accuracy = object_hits as f64 / object_total.max(1) as f64;
    println!("pixel accuracy {accuracy:.3}, on object pixels {object_accuracy:.3} ({object_total} pixels)");
    assert!(object_total > 1000, "the val rooms show objects");
    assert!(accuracy >= PIXEL_ACCURACY, "pixel accuracy {accuracy:.3}");
    assert!(
        object_accuracy >= OBJECT_PIXEL_ACCURACY,
        "object pixel accuracy {object_accuracy:.3}"
    );
}

/// The frames of the four-view window the tests take from a val room's trajectory.
fn window_indices(sim: &Simulation) -> Vec<usize> {
    let count = sim.frame_count();
    (0..4).map(|i| i * (count / 8).max(1)).collect()
}

/// Four views of a val room as the node would sync them.
fn window_frames(sim: &Simulation) -> Vec<SyncedFrame> {
    window_indices(sim)
        .into_iter()
        .map(|index| {
            let frame = sim.frame(index);
            synced_frame(&frame.views[0], (frame.time_secs * 1e9) as i64).unwrap()
        })
        .collect()
}

/// The ground-truth instance ids of the window's views (0: walls and floor), full resolution.
fn window_truth(sim: &Simulation) -> Vec<Vec<u16>> {
    window_indices(sim)
        .into_iter()
        .map(|index| sim.frame(index).views[0].truth.instance.clone())
        .collect()
}

/// The shipped RGB-D reconstruction model and the semantic model.
fn rgbd_and_semantic_models() -> (ReconstructionModel, SemanticModel) {
    init_runtime(None).unwrap_or_else(|e| panic!("{e}"));
    let options = SessionOptions::default();
    (
        ReconstructionModel::load(&models().join("groupforward-mini-rgbd.toml"), &options).unwrap(),
        SemanticModel::load(&models().join("semantic-mini.toml"), &options).unwrap(),
    )
}

#[test]
fn a_window_pass_gives_instances_prototypes_that_name_them() {
    let (mut reconstruction, mut semantic) = rgbd_and_semantic_models();
    let vocabulary = vocabulary();
    let sim = Simulation::new(generate(Split::Val, 0).unwrap()).unwrap();
    let frames = window_frames(&sim);
    let out = window_pass(
        &mut reconstruction,
        Some(&mut semantic),
        &frames,
        &GroupingParams::default(),
    )
    .unwrap();
    assert!(out.semantics_error.is_none(), "{:?}", out.semantics_error);
    assert!(!out.instances.is_empty());
    for instance in &out.instances {
        assert_eq!(instance.prototype.len(), semantic.channels());
        assert!(instance.prototype.iter().all(|v| v.is_finite()));
        let norm = instance.prototype.iter().map(|v| v * v).sum::<f32>().sqrt();
        // A mean of unit features that mostly agree.
        assert!(norm > 0.3 && norm <= 1.0 + 1e-4, "prototype norm {norm}");
    }
    // The biggest instance of a room is its walls and floor.
    let biggest = out.instances.iter().max_by_key(|i| i.support).unwrap();
    assert_eq!(
        vocabulary.hypotheses(&biggest.prototype, 1)[0].0,
        OTHER_PHRASE
    );
}

#[test]
fn features_computed_ahead_give_the_window_the_same_instances_and_prototypes() {
    let (mut reconstruction, mut semantic) = rgbd_and_semantic_models();
    let vocabulary = vocabulary();
    let sim = Simulation::new(generate(Split::Val, 2).unwrap()).unwrap();
    let frames = window_frames(&sim);
    let grouping = GroupingParams::default();
    let in_window =
        window_pass(&mut reconstruction, Some(&mut semantic), &frames, &grouping).unwrap();
    assert_eq!(in_window.features_cached, 0);
    // The node computes every keyframe's features (and their classes under the vocabulary) on
    // arrival but the newest, which completes the window; a stale entry of an older keyframe
    // waits too.
    let mut cache = FeatureCache::with_capacity(8);
    let mut stale = frames[0].clone();
    stale.stamp_nanos -= 1_000_000;
    for frame in std::iter::once(&stale).chain(&frames[..frames.len() - 1]) {
        assert!(cache
            .prepare(&mut semantic, Some(&vocabulary), frame)
            .is_some());
    }
    assert!(
        cache
            .prepare(&mut semantic, Some(&vocabulary), &frames[0])
            .is_none(),
        "computed once per keyframe"
    );
    let mut plain = FeatureCache::with_capacity(8);
    for frame in &frames[..frames.len() - 1] {
        plain.prepare(&mut semantic, None, frame);
    }
    let mut run = |cache: &mut FeatureCache, vocabulary: Option<&Vocabulary>| {
        pass_with_cache(
            &mut reconstruction,
            Some((&mut semantic, cache)),
            vocabulary,
            &frames,
            &grouping,
        )
        .unwrap()
    };
    let named_in_window = run(&mut FeatureCache::with_capacity(0), Some(&vocabulary));
    let ahead = run(&mut cache, Some(&vocabulary));
    assert_eq!(ahead.features_cached, frames.len() - 1);
    assert!(
        cache.is_empty(),
        "the window took its features and dropped the stale one"
    );
    assert!(!ahead.instances.is_empty());
    assert_eq!(ahead.instances, named_in_window.instances);
    assert_eq!(ahead.pixel_instances, named_in_window.pixel_instances);
    // Without a vocabulary the cached features alone give the window's instances.
    assert_eq!(run(&mut plain, None).instances, in_window.instances);
}

/// Depth abs-rel of `predicted` (views of `size` at the model resolution, one after another) against
/// the truth (`truth_size`) at the same pixel centres, and the true depths it was scored on.
fn depth_abs_rel(
    predicted: &[f32],
    size: (usize, usize),
    truth: &[Vec<f32>],
    truth_size: (usize, usize),
) -> (f64, Vec<f32>) {
    let ((w, h), (tw, th)) = (size, truth_size);
    let (mut error, mut scored) = (0.0f64, Vec::new());
    for (view, truth) in predicted.chunks(w * h).zip(truth) {
        for y in 0..h {
            for x in 0..w {
                let sx = ((x as f64 + 0.5) * tw as f64 / w as f64) as usize;
                let sy = ((y as f64 + 0.5) * th as f64 / h as f64) as usize;
                let (d, t) = (view[y * w + x], truth[sy * tw + sx]);
                assert!(d.is_finite() && d > 0.0);
                if t.is_finite() && t > 0.0 {
                    error += f64::from((d - t).abs() / t);
                    scored.push(t);
                }
            }
        }
    }
    (error / scored.len() as f64, scored)
}

/// A shipped reconstruction model by its manifest's file name.
fn reconstruction_model(manifest: &str) -> ReconstructionModel {
    init_runtime(None).unwrap_or_else(|e| panic!("{e}"));
    ReconstructionModel::load(&models().join(manifest), &SessionOptions::default()).unwrap()
}

fn rgbd_model() -> ReconstructionModel {
    reconstruction_model("groupforward-mini-rgbd.toml")
}

fn rgb_model() -> ReconstructionModel {
    reconstruction_model("groupforward-mini-rgb.toml")
}

#[test]
fn the_rgb_model_builds_instances_without_sensor_depth() {
    let mut model = rgb_model();
    let sim = Simulation::new(generate(Split::Val, 1).unwrap()).unwrap();
    let mut frames = window_frames(&sim);
    let truth: Vec<Vec<f32>> = frames
        .iter_mut()
        .map(|f| f.depth.take().unwrap().metres)
        .collect();
    let out = window_pass(&mut model, None, &frames, &GroupingParams::default()).unwrap();
    assert!(
        out.instances.len() >= 2,
        "{} instances",
        out.instances.len()
    );
    let camera = out.views[0].keyframe.camera;
    let predicted: Vec<f32> = out.views.iter().flat_map(|v| v.depth.clone()).collect();
    let (abs_rel, scored) = depth_abs_rel(
        &predicted,
        (camera.width as usize, camera.height as usize),
        &truth,
        (frames[0].rgb.width as usize, frames[0].rgb.height as usize),
    );
    // The best constant guess (the median true depth) as the bar to clear.
    let mut sorted = scored.clone();
    sorted.sort_by(f32::total_cmp);
    let median = sorted[sorted.len() / 2];
    let constant = scored
        .iter()
        .map(|t| f64::from((median - t).abs() / t))
        .sum::<f64>()
        / scored.len() as f64;
    println!(
        "RGB model depth abs-rel {abs_rel:.3} over {} pixels; median guess {constant:.3}",
        scored.len()
    );
    // Measured with the shipped model: 0.131 (the coupled gate model before it: 0.134, the ungated
    // one 0.118; the plain RGB model: 0.138).
    assert!(abs_rel < 0.25, "abs-rel {abs_rel:.3}");
    assert!(
        abs_rel < 0.7 * constant,
        "abs-rel {abs_rel:.3} vs a constant {constant:.3}"
    );
}

#[test]
fn the_posed_rgb_model_triangulates_with_the_views_tf_poses() {
    // The model matches the views along each pixel's ray through the poses it is given: the node
    // must hand them over in the frame and layout it was trained with. Given every view the next
    // view's pose instead, its depth gets worse.
    let mut model = rgb_model();
    assert_eq!(model.mode(), InputMode::RgbPosed);
    let sim = Simulation::new(generate(Split::Val, 2).unwrap()).unwrap();
    let frames = window_frames(&sim);
    let truth: Vec<Vec<f32>> = frames
        .iter()
        .map(|f| f.depth.as_ref().unwrap().metres.clone())
        .collect();
    let truth_size = (frames[0].rgb.width as usize, frames[0].rgb.height as usize);
    let abs_rel_with = |model: &mut ReconstructionModel, poses: &[Rigid]| {
        let views: Vec<View> = frames
            .iter()
            .zip(poses)
            .map(|(f, pose)| View {
                rgb: &f.rgb,
                depth: None,
                camera: f.camera,
                world_from_camera: *pose,
            })
            .collect();
        let prediction = model.predict(&views).unwrap();
        depth_abs_rel(
            &prediction.depth,
            (prediction.width, prediction.height),
            &truth,
            truth_size,
        )
        .0
    };
    let poses: Vec<Rigid> = frames.iter().map(|f| f.world_from_camera).collect();
    let mut shifted = poses.clone();
    shifted.rotate_left(1);
    let right = abs_rel_with(&mut model, &poses);
    let wrong = abs_rel_with(&mut model, &shifted);
    println!(
        "posed RGB depth abs-rel {right:.3} with the true poses, {wrong:.3} with swapped ones"
    );
    // Measured with the shipped model: 0.053 against 0.133 (the model before it: 0.065 against
    // 0.201).
    assert!(right < 0.8 * wrong, "{right:.3} vs {wrong:.3}");
}

/// Instance ARI of one window pass against the sim's instance ids over the pixels the pass lifts,
/// grouped exactly as the node groups (walls and floor are one instance, noise its own label).
/// `channels` keeps only the first embedding channels (the rest zeroed): a broken instance head.
fn window_ari(
    model: &mut ReconstructionModel,
    frames: &[SyncedFrame],
    truth: &[Vec<u16>],
    channels: usize,
) -> f64 {
    let views: Vec<View> = frames.iter().map(View::from).collect();
    let prediction = model.predict(&views).unwrap();
    let mut gaussians = model.to_gaussians(&prediction, &views).unwrap();
    let dims = gaussians.embedding_dim;
    for row in gaussians.embeddings.chunks_mut(dims) {
        row[channels.min(dims)..].iter_mut().for_each(|v| *v = 0.0);
    }
    let grouped = group(&gaussians.embeddings, dims, &GroupingParams::default()).unwrap();
    let pixels = lifted_pixels(&prediction);
    assert_eq!(pixels.len(), grouped.labels.len());
    let truth_labels = truth_of_pixels(&pixels, &prediction, frames, truth);
    let labels: Vec<u32> = grouped
        .labels
        .iter()
        .map(|&l| u32::try_from(l).unwrap_or(u32::MAX))
        .collect();
    adjusted_rand_index(&truth_labels, &labels).unwrap()
}

/// The ground-truth instance id under each lifted model pixel (view-major flat indices at the
/// model's resolution), read at the pixel's centre in the full-resolution `truth`.
fn truth_of_pixels(
    pixels: &[usize],
    prediction: &groupforward::model::reconstruction::Prediction,
    frames: &[SyncedFrame],
    truth: &[Vec<u16>],
) -> Vec<u32> {
    let (w, h) = (prediction.width, prediction.height);
    let (tw, th) = (frames[0].rgb.width as usize, frames[0].rgb.height as usize);
    pixels
        .iter()
        .map(|&i| {
            let (v, y, x) = (i / (w * h), i % (w * h) / w, i % w);
            let sx = ((x as f64 + 0.5) * tw as f64 / w as f64) as usize;
            let sy = ((y as f64 + 0.5) * th as f64 / h as f64) as usize;
            u32::from(truth[v][sy * tw + sx])
        })
        .collect()
}

/// Mean window ARI of `model` over val rooms no training saw, and the same with the instance head
/// cut to its first channel.
fn mean_window_ari(model: &mut ReconstructionModel, rooms: std::ops::Range<u64>) -> (f64, f64) {
    let (mut sum, mut broken, mut count) = (0.0, 0.0, 0.0);
    for index in rooms {
        let sim = Simulation::new(generate(Split::Val, index).unwrap()).unwrap();
        let (frames, truth) = (window_frames(&sim), window_truth(&sim));
        let mut frames = frames;
        if model.mode() != InputMode::Rgbd {
            frames.iter_mut().for_each(|f| f.depth = None);
        }
        let ari = window_ari(model, &frames, &truth, usize::MAX);
        let cut = window_ari(model, &frames, &truth, 1);
        println!("val:{index}: ARI {ari:.3}, first channel only {cut:.3}");
        sum += ari;
        broken += cut;
        count += 1.0;
    }
    (sum / count, broken / count)
}

#[test]
fn the_rgbd_weights_at_192x144_separate_the_objects_of_unseen_rooms_too() {
    // The default's weights exported for a 192 x 144 input (train/export_recon.py --input-size):
    // the camera's views resampled to it, every output at it. Measured on val rooms 0-7: mean
    // window ARI 0.932 (the 128 x 96 file 0.940 below); with the head cut, as below.
    init_runtime(None).unwrap_or_else(|e| panic!("{e}"));
    let mut model = ReconstructionModel::load(
        &models().join("groupforward-mini-rgbd-192x144.toml"),
        &SessionOptions::default(),
    )
    .unwrap();
    assert_separates_objects(&mut model, "RGB-D at 192x144", 0.88);
}

#[test]
fn the_shipped_reconstruction_models_separate_the_objects_of_unseen_rooms() {
    // Measured on val rooms 0-7 with the shipped files (the README's figures are over 400 other
    // val windows at 128x96): RGB-D 0.940, RGB with TF poses 0.856 (per room 0.70-0.97). With the
    // instance head cut to its first channel they score 0.236 and 0.500 (the room, most pixels,
    // still comes out whole): a model that stops separating objects fails here, which "there are
    // instances" never would.
    const RGBD_FLOOR: f64 = 0.90;
    const RGB_FLOOR: f64 = 0.80;
    init_runtime(None).unwrap_or_else(|e| panic!("{e}"));
    let options = SessionOptions::default();
    let mut rgbd =
        ReconstructionModel::load(&models().join("groupforward-mini-rgbd.toml"), &options).unwrap();
    assert_separates_objects(&mut rgbd, "RGB-D", RGBD_FLOOR);
    assert_separates_objects(&mut rgb_model(), "RGB", RGB_FLOOR);
}

/// `model`'s mean window ARI over val rooms 0-7 is at least `floor`, and well above the same
/// model's with its instance head cut to its first channel (so the check can tell a broken head).
fn assert_separates_objects(model: &mut ReconstructionModel, label: &str, floor: f64) {
    let (ari, cut) = mean_window_ari(model, 0..8);
    println!("{label}: mean ARI {ari:.3}, first channel only {cut:.3}");
    assert!(ari >= floor, "{label} mean window ARI {ari:.3}");
    assert!(
        cut < ari - 0.25,
        "{label}: the check cannot tell a broken head: {cut:.3}"
    );
}

/// Per model pixel (view-major), the instance label of one window pass, or `None` where nothing
/// was lifted; and the pixels lifted.
fn window_labels(
    model: &mut ReconstructionModel,
    frames: &[SyncedFrame],
) -> (Vec<Option<i32>>, usize) {
    let views: Vec<View> = frames.iter().map(View::from).collect();
    let mut prediction = model.predict(&views).unwrap();
    use_sensor_depth(&mut prediction, &views);
    let gaussians = model.to_gaussians(&prediction, &views).unwrap();
    let grouped = group(
        &gaussians.embeddings,
        gaussians.embedding_dim,
        &GroupingParams::default(),
    )
    .unwrap();
    let pixels = lifted_pixels(&prediction);
    let mut labels = vec![None; prediction.depth.len()];
    for (&pixel, &label) in pixels.iter().zip(&grouped.labels) {
        labels[pixel] = Some(label);
    }
    (labels, pixels.len())
}

fn with_effects(index: u64, preset: Preset) -> Simulation {
    let mut file = generate(Split::Val, index).unwrap();
    file.apply_preset(preset);
    Simulation::new(file).unwrap()
}

#[test]
fn pixels_without_valid_depth_become_gaussians_only_where_the_models_depth_continues_a_measured_neighbour_at_its_depth(
) {
    let mut model = rgbd_model();
    // 30% random dropout (NaN, as ingest marks every invalid pixel).
    let frames = window_frames(&with_effects(0, Preset::Dropout(0.3)));
    let views: Vec<View> = frames.iter().map(View::from).collect();
    let mut prediction = model.predict(&views).unwrap();
    let model_depth = prediction.depth.clone();
    let from_model = use_sensor_depth(&mut prediction, &views);
    let (w, h) = (prediction.width, prediction.height);
    let (tw, th) = (frames[0].rgb.width as usize, frames[0].rgb.height as usize);
    let sensor_at = |i: usize| {
        let (v, y, x) = (i / (w * h), i % (w * h) / w, i % w);
        let sx = ((x as f64 + 0.5) * tw as f64 / w as f64) as usize;
        let sy = ((y as f64 + 0.5) * th as f64 / h as f64) as usize;
        frames[v].depth.as_ref().unwrap().metres[sy * tw + sx]
    };
    let valid = |z: f32| z.is_finite() && z > 0.0;
    let lifted = lifted_pixels(&prediction);
    let (mut invalid_seen, mut invalid_lifted) = (0, 0);
    for (i, &model_z) in model_depth.iter().enumerate() {
        let sensor = sensor_at(i);
        let is_lifted = lifted.binary_search(&i).is_ok();
        if valid(sensor) {
            assert!(is_lifted, "pixel {i} has a measurement");
            assert_eq!(
                prediction.depth[i], sensor,
                "pixel {i} is lifted at its measurement"
            );
            continue;
        }
        invalid_seen += 1;
        let (x, y) = (i % w, i % (w * h) / w);
        let neighbours = [
            (x > 0).then(|| i - 1),
            (x + 1 < w).then(|| i + 1),
            (y > 0).then(|| i - w),
            (y + 1 < h).then(|| i + w),
        ];
        let agrees = |s: &f32| valid(*s) && (s - model_z).abs() <= MODEL_DEPTH_AGREEMENT * *s;
        // The sensor pixels this pixel covers first, then its 4 neighbours' samples.
        let span = |i: usize, model: usize, sensor: usize| {
            let start = i * sensor / model;
            start..((i + 1) * sensor).div_ceil(model).clamp(start + 1, sensor)
        };
        let depth = &frames[i / (w * h)].depth.as_ref().unwrap().metres;
        let footprint: Vec<f32> = span(y, h, th)
            .flat_map(|sy| span(x, w, tw).map(move |sx| depth[sy * tw + sx]))
            .filter(agrees)
            .collect();
        let agreeing: Vec<f32> = if footprint.is_empty() {
            neighbours
                .into_iter()
                .flatten()
                .map(sensor_at)
                .filter(agrees)
                .collect()
        } else {
            footprint
        };
        assert_eq!(
            is_lifted,
            !agreeing.is_empty(),
            "pixel {i} without a measurement"
        );
        if is_lifted {
            invalid_lifted += 1;
            let nearest = agreeing
                .iter()
                .map(|s| (s - model_z).abs())
                .fold(f32::INFINITY, f32::min);
            assert!(
                agreeing.contains(&prediction.depth[i])
                    && (prediction.depth[i] - model_z).abs() == nearest,
                "pixel {i} at the agreeing neighbour's depth nearest the model's"
            );
        }
    }
    assert_eq!(invalid_lifted, from_model);
    // Both kinds occur: the rule is not all or nothing on this window.
    assert!(
        invalid_lifted > 0 && invalid_lifted < invalid_seen,
        "{invalid_lifted} of {invalid_seen}"
    );
    assert!(invalid_seen > prediction.depth.len() / 5, "{invalid_seen}");

    // No valid depth anywhere: nothing is built, and the output says why.
    let mut blind = frames.clone();
    for frame in &mut blind {
        frame.depth.as_mut().unwrap().metres.fill(f32::NAN);
    }
    let out = window_pass(&mut model, None, &blind, &GroupingParams::default()).unwrap();
    assert!(out.instances.is_empty() && out.gaussians == 0);
    assert!(out.skipped.as_deref().unwrap().contains("no valid depth"));
    assert_eq!(out.invalid_depth_pixels, prediction.depth.len());
}

#[test]
fn thirty_percent_depth_dropout_leaves_the_window_s_instances_as_they_were() {
    // Measured on val rooms 0-3: ARI between the clean and the 30%-dropout window's instance
    // labels on the pixels both lift 0.986 with the model's input filled as in training (0.172
    // with the fill switched off: dropped pixels went in as the window's centre point).
    const FLOOR: f64 = 0.85;
    let mut model = rgbd_model();
    let mut sum = 0.0;
    for index in 0..4 {
        let (clean, _) = window_labels(
            &mut model,
            &window_frames(&with_effects(index, Preset::Clean)),
        );
        let (dropped, lifted) = window_labels(
            &mut model,
            &window_frames(&with_effects(index, Preset::Dropout(0.3))),
        );
        let both: Vec<(u32, u32)> = clean
            .iter()
            .zip(&dropped)
            .filter_map(|(a, b)| Some(((*a)?, (*b)?)))
            .map(|(a, b)| {
                let id = |l: i32| u32::try_from(l).unwrap_or(u32::MAX);
                (id(a), id(b))
            })
            .collect();
        assert!(both.len() * 2 > lifted, "{} of {lifted}", both.len());
        let (a, b): (Vec<u32>, Vec<u32>) = both.into_iter().unzip();
        let ari = adjusted_rand_index(&a, &b).unwrap();
        println!("val:{index}: clean vs 30% dropout ARI {ari:.3}");
        sum += ari;
    }
    let mean = sum / 4.0;
    println!("mean {mean:.3}");
    assert!(mean >= FLOOR, "clean vs 30% dropout ARI {mean:.3}");
}

/// Objects of one window found as themselves: the instance holding most of an object's lifted
/// pixels is neither noise nor the room's (the instance holding most wall and floor pixels), and
/// holds more of this object than of any other (objects with at least 50 lifted pixels).
fn objects_found(labels: &[i32], truth: &[u32]) -> (usize, usize) {
    use std::collections::HashMap;
    let mut by_object: HashMap<u32, HashMap<i32, usize>> = HashMap::new();
    let mut by_label: HashMap<i32, HashMap<u32, usize>> = HashMap::new();
    for (&l, &t) in labels.iter().zip(truth) {
        *by_object.entry(t).or_default().entry(l).or_default() += 1;
        *by_label.entry(l).or_default().entry(t).or_default() += 1;
    }
    let room = by_object.get(&0).and_then(majority);
    let (mut found, mut objects) = (0, 0);
    for (&object, counts) in by_object.iter().filter(|(&t, _)| t > 0) {
        if counts.values().sum::<usize>() < 50 {
            continue;
        }
        objects += 1;
        let Some(label) = majority(counts).filter(|&l| l >= 0 && Some(l) != room) else {
            continue;
        };
        if majority(&by_label[&label]) == Some(object) {
            found += 1;
        }
    }
    (found, objects)
}

/// The key with the largest count (ties to the smallest key).
fn majority<K: Copy + Ord>(counts: &std::collections::HashMap<K, usize>) -> Option<K> {
    counts
        .iter()
        .max_by_key(|(k, n)| (**n, std::cmp::Reverse(**k)))
        .map(|(k, _)| *k)
}

#[test]
fn the_vote_split_parts_identical_neighbours_the_embeddings_join() {
    // Rows of identical objects (the `layouts` split, rooms the model never trained on): the
    // RGB-D model's centre votes tell apart what its embeddings join. Measured on layouts rooms
    // 0-5 with the shipped file: 44 of 59 objects found with the split against 37 without (on
    // the 60 windows of layouts 40-99: 71 against 65%). With the split a no-op this fails.
    let mut model = rgbd_model();
    let (mut with_split, mut without, mut objects) = (0, 0, 0);
    for index in 0..6 {
        let sim = Simulation::new(generate(Split::Layouts, index).unwrap()).unwrap();
        let (frames, truth) = (window_frames(&sim), window_truth(&sim));
        let views: Vec<View> = frames.iter().map(View::from).collect();
        let prediction = model.predict(&views).unwrap();
        let votes = prediction
            .votes
            .as_ref()
            .expect("the RGB-D model has votes");
        assert_eq!(votes.height * 2, prediction.height);
        let gaussians = model.to_gaussians(&prediction, &views).unwrap();
        let (w, h) = (prediction.width, prediction.height);
        let pixels = lifted_pixels(&prediction);
        let truth_labels = truth_of_pixels(&pixels, &prediction, &frames, &truth);
        let params = GroupingParams::default();
        let grouped = group(&gaussians.embeddings, gaussians.embedding_dim, &params).unwrap();
        let point_votes = votes.of_pixels(&pixels, w, h, model.points_scale());
        let mut split = grouped.labels.clone();
        split_by_votes(&mut split, &point_votes, &params.vote_split.unwrap());
        let (found_split, n) = objects_found(&split, &truth_labels);
        let (found_plain, _) = objects_found(&grouped.labels, &truth_labels);
        println!("layouts:{index}: {found_split} / {found_plain} of {n} objects found");
        with_split += found_split;
        without += found_plain;
        objects += n;
    }
    println!("with the vote split {with_split}, without {without}, of {objects}");
    assert!(
        with_split >= without + 3,
        "{with_split} against {without} of {objects}"
    );
}
