#![allow(clippy::unwrap_used)]
//! Grouping: clusters recovered on synthetic embeddings, and every hard case (identical points,
//! too few points, noise only, touching clusters, 1-D data, tiny temperatures, zero vectors,
//! identical or empty clusters to merge) stays finite and meaningful.

use groupforward::group::blobs::blobs;
use groupforward::group::hdbscan::{hdbscan, HdbscanParams};
use groupforward::group::semantics::MeasuredSize;
use groupforward::group::{
    assignment_probabilities, embedding_distance, group, merge_close_clusters, GroupError,
    Grouping, GroupingParams, ResidualPass,
};
use groupforward::recon::metrics::adjusted_rand_index;

fn ari(labels: &[i32], truth: &[u32]) -> f64 {
    let mapped: Vec<u32> = labels.iter().map(|&l| (l + 1) as u32).collect();
    adjusted_rand_index(&mapped, truth).unwrap()
}

fn params(min_cluster_size: usize, min_samples: usize) -> HdbscanParams {
    HdbscanParams {
        min_cluster_size,
        min_samples,
        allow_single_cluster: false,
    }
}

#[test]
fn separated_blobs_are_recovered() {
    let (points, truth) = blobs(3000, 8, 6, 1.0, 1);
    let result = hdbscan(&points, 8, &params(60, 10)).unwrap();
    assert_eq!(result.n_clusters, 6);
    let noise = result.labels.iter().filter(|l| **l < 0).count();
    assert!(noise < 150, "{noise} noise points");
    assert!(ari(&result.labels, &truth) > 0.95);
}

#[test]
fn clustering_is_deterministic_across_thread_counts() {
    let (points, _) = blobs(4000, 8, 10, 1.5, 2);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| hdbscan(&points, 8, &params(40, 8)).unwrap())
    };
    let one = run(1);
    assert_eq!(one, run(2));
    assert_eq!(one, run(4));
}

#[test]
fn all_identical_points_are_one_cluster_or_noise_never_nan() {
    let points = vec![0.25f32; 200 * 8];
    let strict = hdbscan(&points, 8, &params(20, 5)).unwrap();
    assert_eq!(strict.n_clusters, 0);
    assert!(strict.labels.iter().all(|l| *l == -1));
    let single = hdbscan(
        &points,
        8,
        &HdbscanParams {
            allow_single_cluster: true,
            ..params(20, 5)
        },
    )
    .unwrap();
    assert_eq!(single.n_clusters, 1);
    assert!(single.labels.iter().all(|l| *l == 0));
}

#[test]
fn fewer_points_than_min_cluster_size_are_noise() {
    let (points, _) = blobs(30, 8, 1, 1.0, 3);
    let result = hdbscan(&points, 8, &params(60, 10)).unwrap();
    assert_eq!(result.labels, vec![-1; 30]);
    assert!(hdbscan(&[], 8, &params(60, 10)).unwrap().labels.is_empty());
    assert!(
        hdbscan(&[1.0, 2.0, 3.0], 2, &params(60, 10)).is_err(),
        "ragged rows"
    );
    assert!(hdbscan(&[f32::NAN; 8], 8, &params(60, 10)).is_err());
}

#[test]
fn uniform_noise_yields_no_confident_clusters() {
    // Scattered points with no density structure.
    let (points, _) = blobs(500, 8, 500, 0.0, 4);
    let result = hdbscan(&points, 8, &params(60, 10)).unwrap();
    assert!(
        result.n_clusters <= 1,
        "{} clusters in noise",
        result.n_clusters
    );
    assert!(result
        .labels
        .iter()
        .all(|l| *l >= -1 && *l < result.n_clusters as i32));
}

#[test]
fn two_touching_clusters_stay_two() {
    // An 8-d unit Gaussian cloud has radius ≈ √8 ≈ 2.8: centres 6 apart, the clouds touch.
    let mut points = Vec::new();
    let mut truth = Vec::new();
    let (a, _) = blobs(800, 8, 1, 1.0, 5);
    let (b, _) = blobs(800, 8, 1, 1.0, 6);
    let (ca, cb) = (mean(&a), mean(&b));
    for (row_a, row_b) in a.chunks(8).zip(b.chunks(8)) {
        points.extend(row_a.iter().zip(&ca).map(|(v, c)| v - c));
        truth.push(0);
        points.extend(
            row_b
                .iter()
                .zip(&cb)
                .enumerate()
                .map(|(d, (v, c))| v - c + if d == 0 { 6.0 } else { 0.0 }),
        );
        truth.push(1);
    }
    let result = hdbscan(&points, 8, &params(60, 10)).unwrap();
    assert_eq!(result.n_clusters, 2);
    // Points in the contact zone may be noise (Python hdbscan leaves ~12% there); the rest split
    // exactly along the truth.
    let kept: Vec<usize> = (0..truth.len())
        .filter(|&i| result.labels[i] >= 0)
        .collect();
    let noise = 1.0 - kept.len() as f64 / truth.len() as f64;
    assert!(noise < 0.3, "{noise} noise");
    let labels: Vec<i32> = kept.iter().map(|&i| result.labels[i]).collect();
    let truth: Vec<u32> = kept.iter().map(|&i| truth[i]).collect();
    assert!(ari(&labels, &truth) > 0.99, "{}", ari(&labels, &truth));
}

fn mean(points: &[f32]) -> Vec<f32> {
    let n = (points.len() / 8) as f32;
    (0..8)
        .map(|d| points.chunks(8).map(|r| r[d]).sum::<f32>() / n)
        .collect()
}

#[test]
fn one_dimensional_data_in_eight_dimensions() {
    // Two segments on one line, 1 apart, every other coordinate zero: a degenerate KD-tree.
    let mut points = Vec::new();
    let mut truth = Vec::new();
    for i in 0..400 {
        let (x, label) = if i % 2 == 0 {
            (i as f32 * 0.001, 0)
        } else {
            (1.4 + i as f32 * 0.001, 1)
        };
        let mut row = [0.0f32; 8];
        row[3] = x;
        points.extend_from_slice(&row);
        truth.push(label);
    }
    let result = hdbscan(&points, 8, &params(30, 5)).unwrap();
    assert_eq!(result.n_clusters, 2);
    assert!(ari(&result.labels, &truth) > 0.99);
}

#[test]
fn tiny_temperatures_give_finite_one_hot_assignments() {
    let centroids = vec![vec![1.0, 0.0], vec![0.0, 1.0]];
    let mut p = Vec::new();
    for tau in [1.0, 1e-3, 1e-6, 1e-30] {
        assignment_probabilities(&[0.9, 0.1], &centroids, tau, &mut p);
        assert!(p.iter().all(|v| v.is_finite()), "tau {tau}: {p:?}");
        assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        assert!(p[0] >= p[1]);
    }
    assert_eq!(p, vec![1.0, 0.0]);
    // Equidistant: an even split at any temperature.
    assignment_probabilities(&[0.5, 0.5], &centroids, 1e-6, &mut p);
    assert!((p[0] - 0.5).abs() < 1e-6);
}

#[test]
fn grouping_assigns_every_embedding_and_marks_zero_vectors_noise() {
    // Unit-sphere clusters, as trained embeddings are.
    let (mut points, truth) = blobs(6000, 8, 5, 0.3, 7);
    for row in points.chunks_mut(8).take(10) {
        row.iter_mut().for_each(|v| *v = 0.0);
    }
    let params = GroupingParams {
        max_cluster_points: 2000,
        ..GroupingParams::default()
    };
    let result = group(&points, 8, &params).unwrap();
    assert_eq!(result.labels.len(), 6000);
    assert_eq!(result.centroids.len(), 5);
    assert!(
        result.labels[..10].iter().all(|l| *l == -1),
        "zero vectors are noise"
    );
    assert!(ari(&result.labels[10..], &truth[10..]) > 0.98);
    for c in &result.centroids {
        let norm = c.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-4);
    }
    assert!(group(
        &points,
        8,
        &GroupingParams {
            temperature: 0.0,
            ..params
        }
    )
    .is_err());
}

fn with_the_residual_pass() -> GroupingParams {
    let params = GroupingParams::default();
    assert_eq!(
        params.residual,
        Some(ResidualPass::default()),
        "on by default"
    );
    params
}

/// The grouping of 8-d `points` by the first pass alone, and with the residual pass (the default).
fn without_and_with_the_residual_pass(points: &[f32]) -> (Grouping, Grouping) {
    let first_pass_only = GroupingParams {
        residual: None,
        ..GroupingParams::default()
    };
    (
        group(points, 8, &first_pass_only).unwrap(),
        group(points, 8, &with_the_residual_pass()).unwrap(),
    )
}

#[test]
fn small_objects_left_as_noise_by_the_first_pass_become_instances_in_the_residual_pass() {
    // Four large objects and two of 24 and 20 embeddings: fewer than the first pass's
    // min_cluster_size (30), so HDBSCAN calls them noise; the second pass over the noise alone
    // finds each.
    let (mut points, _) = blobs(4000, 8, 4, 0.3, 21);
    let (small, _) = blobs(44, 8, 2, 0.3, 22);
    points.extend_from_slice(&small);
    let (before, after) = without_and_with_the_residual_pass(&points);
    assert!(before.labels[4000..].iter().all(|&l| l == -1));
    // blobs() interleaves its centres: even rows are the first small object, odd the second.
    let (a, b) = (after.labels[4000], after.labels[4001]);
    let first_new = before.centroids.len() as i32;
    assert!(
        a >= first_new && b >= first_new && a != b,
        "two new instances"
    );
    for (k, &label) in after.labels[4000..].iter().enumerate() {
        assert_eq!(label, if k % 2 == 0 { a } else { b });
    }
    // The first pass's instances are untouched, and nothing else joins the new ones.
    assert_eq!(after.labels[..4000], before.labels[..4000]);
    assert_eq!(
        after.centroids[..before.centroids.len()],
        before.centroids[..]
    );
    assert_eq!(after.labels.iter().filter(|&&l| l >= first_new).count(), 44);
}

#[test]
fn scattered_noise_stays_noise_in_the_residual_pass() {
    // What the first pass leaves is a lone small object, or scattered points: the second pass may
    // take the whole residual for one cluster, which keeps its place only if min_cluster_size
    // points lie within the noise distance of it.
    let (mut points, _) = blobs(3000, 8, 3, 0.3, 23);
    let (scattered, _) = blobs(60, 8, 60, 0.3, 24);
    points.extend_from_slice(&scattered);
    let (before, after) = without_and_with_the_residual_pass(&points);
    assert_eq!(after, before);
    // A lone small object among them is found.
    let (small, _) = blobs(20, 8, 1, 0.2, 25);
    points.extend_from_slice(&small);
    let after = group(&points, 8, &with_the_residual_pass()).unwrap();
    assert_eq!(after.centroids.len(), before.centroids.len() + 1);
    let label = after.labels[3060];
    assert!(after.labels[3060..].iter().all(|&l| l == label));
    assert_eq!(after.labels.iter().filter(|&&l| l == label).count(), 20);
}

#[test]
fn each_embedding_takes_the_argmax_of_its_assignment_softmax() {
    // The window labels each embedding with its nearest centroid; that is the paper's rule (the
    // most probable instance under the assignment softmax, §5.4) for every temperature.
    let (points, _) = blobs(3000, 8, 6, 0.8, 11);
    for temperature in [0.05f32, 1.0] {
        let params = GroupingParams {
            max_cluster_points: 1500,
            temperature,
            ..GroupingParams::default()
        };
        let result = group(&points, 8, &params).unwrap();
        assert!(result.centroids.len() >= 2);
        let mut probabilities = Vec::new();
        for (row, &label) in points.chunks(8).zip(&result.labels) {
            let norm = row.iter().map(|v| v * v).sum::<f32>().sqrt();
            let unit: Vec<f32> = row.iter().map(|v| v / norm).collect();
            assignment_probabilities(&unit, &result.centroids, temperature, &mut probabilities);
            let best = (0..probabilities.len())
                .max_by(|&a, &b| probabilities[a].total_cmp(&probabilities[b]))
                .unwrap();
            let near = embedding_distance(&unit, &result.centroids[best]) <= params.noise_distance;
            assert_eq!(label, if near { best as i32 } else { -1 });
        }
    }
}

mod semantics {
    use glam::{DQuat, DVec3, Quat, Vec3};
    use groupforward::group::semantics::{propagate, prototypes, LabelledView};
    use groupforward::recon::camera::Camera;
    use groupforward::recon::gaussians::Gaussians;
    use groupforward::recon::Rigid;

    #[test]
    fn prototypes_are_masked_means_over_views_and_empty_instances_stay_zero() {
        let labels_a = [0, 0, 1, -1];
        // Channel after channel: pixels (1, 0), (3, 0), (0, 2), (9, 9).
        let features_a = [1.0, 3.0, 0.0, 9.0, 0.0, 0.0, 2.0, 9.0];
        let labels_b = [1, 0];
        let features_b = [0.0, 5.0, 4.0, 0.0];
        let views = [
            LabelledView {
                labels: &labels_a,
                features: &features_a,
            },
            LabelledView {
                labels: &labels_b,
                features: &features_b,
            },
        ];
        let (protos, counts) = prototypes(&views, 2, 3).unwrap();
        assert_eq!(counts, vec![3, 2, 0]);
        assert_eq!(protos[0], vec![3.0, 0.0]);
        assert_eq!(protos[1], vec![0.0, 3.0]);
        assert_eq!(protos[2], vec![0.0, 0.0], "never seen: zero, not NaN");
        let bad = [LabelledView {
            labels: &labels_b,
            features: &[f32::NAN, 0.0, 0.0, 0.0],
        }];
        assert!(prototypes(&bad, 2, 3).is_err());
        // A non-finite feature no instance covers (view a's unlabelled pixel) harms nothing.
        let mut stray = features_a;
        stray[3] = f32::NAN;
        stray[7] = f32::INFINITY;
        let unharmed = [LabelledView {
            labels: &labels_a,
            features: &stray,
        }];
        let (protos, _) = prototypes(&unharmed, 2, 3).unwrap();
        assert_eq!(protos[0], vec![2.0, 0.0]);
        assert_eq!(protos[1], vec![0.0, 2.0]);
        let short = [LabelledView {
            labels: &labels_b,
            features: &[0.0; 3],
        }];
        assert!(prototypes(&short, 2, 3).is_err());
    }

    #[test]
    fn propagation_renders_instances_and_their_features_into_a_new_view() {
        // Two walls of Gaussians 3 m ahead: left one instance 0, right one instance 1.
        let mut g = Gaussians::with_dims(0, 0);
        let mut assignment = Vec::new();
        for i in 0..40 {
            for j in 0..20 {
                let x = -1.0 + i as f32 * 0.05;
                let y = -0.5 + j as f32 * 0.05;
                g.push(
                    Vec3::new(x, y, 3.0),
                    0.95,
                    Vec3::splat(0.04),
                    Quat::IDENTITY,
                    Vec3::ONE,
                    &[],
                    &[],
                );
                assignment.extend_from_slice(if x < 0.0 {
                    &[0.98, 0.02]
                } else {
                    &[0.03, 0.97]
                });
            }
        }
        let prototypes = vec![vec![1.0, 0.0, 0.0], vec![0.0, 1.0, 0.0]];
        let camera = Camera::from_fov(64, 48, 1.2).unwrap();
        // Camera at the origin looking along +z (world = camera frame).
        let pose = Rigid::new(DQuat::IDENTITY, DVec3::ZERO);
        let out = propagate(&g, &assignment, &prototypes, &camera, &pose, 0.5).unwrap();
        let at = |u: usize, v: usize| out.labels[v * 64 + u];
        assert_eq!(at(20, 24), 0);
        assert_eq!(at(44, 24), 1);
        assert_eq!(at(32, 2), -1, "nothing rendered above the walls");
        let feature = &out.features[(24 * 64 + 20) * 3..(24 * 64 + 20) * 3 + 3];
        assert!(
            feature[0] > 0.9 && feature[1] < 0.1 && feature[2] == 0.0,
            "{feature:?}"
        );
        let p = &out.probabilities[(24 * 64 + 44) * 2..(24 * 64 + 44) * 2 + 2];
        assert!((p[0] + p[1] - 1.0).abs() < 1e-5 && p[1] > 0.9);
        assert!(out.features.iter().all(|f| f.is_finite()));
    }
}

fn vocabulary(temperature: f32) -> groupforward::group::semantics::Vocabulary {
    groupforward::group::semantics::Vocabulary {
        phrases: vec!["chair".into(), "table".into(), "other".into()],
        embeddings: vec![
            vec![1.0, 0.0, 0.0],
            vec![0.0, 1.0, 0.0],
            vec![0.0, 0.0, 1.0],
        ],
        temperature,
        priors: groupforward::group::semantics::ClassPriors::builtin(),
    }
}

#[test]
fn hypotheses_rank_phrases_by_prototype_cosine() {
    let names = vocabulary(0.05).hypotheses(&[0.2, 0.9, 0.1], 2);
    assert_eq!(names.len(), 2);
    assert_eq!(names[0].0, "table");
    assert!(names[0].1 > names[1].1 && names[0].1 <= 1.0 && names[1].1 > 0.0);
    // Scale does not matter: the prototype is a mean of unit features, not unit itself.
    let scaled = vocabulary(0.05).hypotheses(&[0.02, 0.09, 0.01], 2);
    assert_eq!(names, scaled);
}

/// A measured length without a height (a height that is no number rules out no name).
fn length_only(length_m: f64) -> MeasuredSize {
    MeasuredSize {
        length_m,
        height_m: f64::NAN,
    }
}

#[test]
fn a_name_whose_objects_are_never_that_long_gives_way_to_the_next_object_name() {
    // The built-in priors: no chair is longer than 0.52 m, no table than 1.38 m.
    let v = vocabulary(0.05);
    let chairish = [0.9, 0.85, 0.3];
    let best = |length: Option<f64>| {
        v.ranked(
            &v.probabilities_given(&chairish, length.map(length_only)),
            1,
        )[0]
        .0
        .clone()
    };
    assert_eq!(best(None), "chair");
    assert_eq!(best(Some(0.5)), "chair", "a chair's length");
    assert_eq!(
        best(Some(1.0)),
        "chair",
        "a chair with a piece of what it touches"
    );
    assert_eq!(
        best(Some(1.2)),
        "table",
        "longer than two chairs side by side"
    );
    let p = v.probabilities_given(&chairish, Some(length_only(1.2)));
    assert_eq!(p[0], 0.0);
    assert_eq!(
        p[2], 0.0,
        "structure takes no share: the features called it an object"
    );
    assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{p:?}");
    // Nothing admits 10 m: the features' name stands. So it does for structure, any length,
    // and for a length that is no number.
    assert_eq!(best(Some(10.0)), "chair");
    assert_eq!(
        v.ranked(
            &v.probabilities_given(&[0.1, 0.3, 0.9], Some(length_only(0.3))),
            1
        )[0]
        .0,
        "other"
    );
    assert_eq!(
        v.probabilities_given(&chairish, Some(length_only(f64::NAN))),
        v.probabilities(&chairish)
    );
    // A name the features give no real share does not take over: a chair 1.2 m long whose
    // features leave the table a trace is a chair with a piece of something attached.
    let sure = [0.9, 0.5, 0.3];
    assert!(v.probabilities(&sure)[1] < groupforward::group::semantics::MIN_ADMITTED_SHARE);
    assert_eq!(
        v.ranked(&v.probabilities_given(&sure, Some(length_only(1.2))), 1)[0].0,
        "chair"
    );
    // A vocabulary without priors names by the features alone.
    let mut without = v.clone();
    without.priors = Default::default();
    assert_eq!(
        without.ranked(
            &without.probabilities_given(&chairish, Some(length_only(1.2))),
            1
        )[0]
        .0,
        "chair"
    );
}

#[test]
fn a_name_whose_objects_are_never_that_tall_gives_way_to_the_next_object_name() {
    // The built-in priors: no box is taller than 0.34 m, no chair than 1.06 m. A chair whose
    // colours the features read as a box's (benchmark 13214's brown chair, 0.99 m tall).
    let mut v = vocabulary(0.05);
    v.phrases[1] = "box".into();
    let boxish = [0.85, 0.9, 0.3];
    let best = |v: &groupforward::group::semantics::Vocabulary, height_m: f64| {
        let size = MeasuredSize {
            length_m: 0.45,
            height_m,
        };
        v.ranked(&v.probabilities_given(&boxish, Some(size)), 1)[0]
            .0
            .clone()
    };
    assert_eq!(best(&v, 0.3), "box", "a box's height");
    assert_eq!(best(&v, 0.6), "box", "a box on another");
    assert_eq!(best(&v, 0.95), "chair", "taller than two boxes stacked");
    assert_eq!(
        best(&v, f64::NAN),
        "box",
        "a height not measured rules out nothing"
    );
    let size = MeasuredSize {
        length_m: 0.45,
        height_m: 0.95,
    };
    let p = v.probabilities_given(&boxish, Some(size));
    assert_eq!(p[1], 0.0, "{p:?}");
    assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{p:?}");
    // Where the chair's name stands, the box keeps its share: one may rest on the chair (a
    // pillow merged into its bed, benchmark 14017).
    let chairish = [0.9, 0.85, 0.3];
    let plain = v.probabilities(&chairish);
    assert_eq!(v.probabilities_given(&chairish, Some(size)), plain);
    // A name without a tallest object admits any height.
    v.phrases[1] = "whiteboard".into();
    assert_eq!(best(&v, 0.95), "whiteboard");
}

#[test]
fn a_name_whose_objects_are_all_wider_gives_way_to_the_next_object_name() {
    use groupforward::group::vocabulary::NAME_SMALLEST_SHARE;
    // The built-in priors: no sofa is less than 0.77 m deep; a trash bin has no depth prior. A
    // trash bin the features read as a sofa's (benchmark 14403, 0.4 m across).
    let mut v = vocabulary(0.05);
    v.phrases[0] = "sofa".into();
    v.phrases[1] = "trash bin".into();
    let sofaish = [0.9, 0.85, 0.3];
    let smallest = v.priors.smallest_depth("sofa").unwrap();
    let best = |v: &groupforward::group::semantics::Vocabulary, length_m: f64| {
        v.ranked(
            &v.probabilities_given(&sofaish, Some(length_only(length_m))),
            1,
        )[0]
        .0
        .clone()
    };
    assert_eq!(best(&v, 1.9), "sofa", "a sofa's length");
    assert_eq!(
        best(&v, NAME_SMALLEST_SHARE * smallest + 0.01),
        "sofa",
        "a piece of one, as wide as a good share of its depth"
    );
    assert_eq!(best(&v, 0.4), "trash bin", "narrower than any sofa is deep");
    assert_eq!(
        best(&v, f64::NAN),
        "sofa",
        "a length not measured rules out nothing"
    );
    let p = v.probabilities_given(&sofaish, Some(length_only(0.4)));
    assert_eq!(p[0], 0.0, "{p:?}");
    assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{p:?}");
    // Where the admitted names hold too little, the name stands (a piece of a larger object).
    let surely_sofa = [1.0, 0.0, 0.0];
    let p = v.probabilities_given(&surely_sofa, Some(length_only(0.4)));
    assert_eq!(p, v.probabilities(&surely_sofa));
    // A name without a smallest depth admits any small length.
    v.phrases[0] = "whiteboard".into();
    assert_eq!(best(&v, 0.4), "whiteboard");
}

#[test]
fn the_object_list_leaves_out_structure_and_small_pieces_named_unsurely_or_seen_once() {
    use groupforward::group::semantics::{
        CONFIDENT_NAME, MIN_LISTED_GAUSSIANS, MIN_SMALL_SIGHTINGS, SURE_NAME,
    };
    let v = vocabulary(0.05);
    let score = |prototype: &[f32]| v.hypotheses(prototype, 1)[0].1;
    let sure = [1.0, 0.0, 0.0];
    let confident = [1.0, 0.85, 0.0];
    let unsure = [0.5, 0.48, 0.0];
    assert!(score(&sure) >= SURE_NAME);
    assert!(score(&confident) >= CONFIDENT_NAME && score(&confident) < SURE_NAME);
    assert!(score(&unsure) < CONFIDENT_NAME);
    let small = MIN_LISTED_GAUSSIANS - 1;
    assert!(
        v.is_listed(&confident, small, 2),
        "a small object named confidently, seen again"
    );
    assert!(
        !v.is_listed(&confident, small, 1),
        "a small object named confidently, seen by one window only: tentative"
    );
    assert!(
        v.is_listed(&sure, small, 1),
        "a small object named surely, seen by one window only"
    );
    assert_eq!(MIN_SMALL_SIGHTINGS, 2);
    assert!(
        v.is_listed(&unsure, MIN_LISTED_GAUSSIANS, 1),
        "a large one named unsurely, seen once"
    );
    assert!(
        !v.is_listed(&unsure, small, 10),
        "a small piece named unsurely"
    );
    assert!(
        !v.is_listed(&[0.0, 0.0, 1.0], 10_000, 10),
        "structure, however large"
    );
    // Without semantics there are no names to judge: listed.
    assert!(v.is_listed(&[], 1, 1));
    // Tentative candidates for queries: small pieces the list holds back whose best name scores
    // at least TENTATIVE_NAME; never what the list holds, structure, or a piece named vaguely.
    use groupforward::group::semantics::TENTATIVE_NAME;
    assert!(
        v.is_tentative(&confident, small, 1),
        "named confidently, seen once"
    );
    assert!(!v.is_tentative(&confident, small, 2), "listed");
    assert!(!v.is_tentative(&sure, small, 1), "listed");
    assert!(score(&unsure) >= TENTATIVE_NAME);
    assert!(v.is_tentative(&unsure, small, 3), "named unsurely");
    let vague = [0.5, 0.5, 0.45];
    assert!(score(&vague) < TENTATIVE_NAME);
    assert!(!v.is_tentative(&vague, small, 1), "named vaguely");
    assert!(!v.is_tentative(&[0.0, 0.0, 1.0], small, 1), "structure");
    assert!(!v.is_tentative(&[], 1, 1));
}

#[test]
fn same_kind_means_the_same_best_name_and_never_structure() {
    let v = vocabulary(0.05);
    assert!(
        v.same_kind(&[0.9, 0.1, 0.0], &[0.7, 0.3, 0.1]),
        "two chairs"
    );
    assert!(
        !v.same_kind(&[0.9, 0.1, 0.0], &[0.1, 0.9, 0.0]),
        "a chair, a table"
    );
    assert!(
        !v.same_kind(&[0.0, 0.1, 0.9], &[0.1, 0.0, 0.9]),
        "walls are no kind"
    );
    assert!(!v.same_kind(&[], &[0.9, 0.1, 0.0]), "no semantics");
    assert!(!v.same_kind(&[0.0, 0.0, 0.0], &[0.0, 0.0, 0.0]));
    // The memo answers as the vocabulary does, asked again and in either order.
    let prototypes: [&[f32]; 6] = [
        &[0.9, 0.1, 0.0],
        &[0.7, 0.3, 0.1],
        &[0.1, 0.9, 0.0],
        &[0.0, 0.1, 0.9],
        &[],
        &[0.0, 0.0, 0.0],
    ];
    let memo = groupforward::group::semantics::KindMemo::new(&v);
    for _ in 0..2 {
        for a in prototypes {
            for b in prototypes {
                assert_eq!(memo.same_kind(a, b), v.same_kind(a, b), "{a:?} {b:?}");
            }
        }
    }
}

#[test]
fn hypotheses_of_zero_or_empty_prototypes_are_empty() {
    assert!(vocabulary(0.05).hypotheses(&[0.0, 0.0, 0.0], 3).is_empty());
    assert!(vocabulary(0.05).hypotheses(&[], 3).is_empty());
    assert!(vocabulary(0.05)
        .hypotheses(&[f32::NAN, 0.0, 0.0], 3)
        .is_empty());
}

#[test]
fn hypothesis_scores_stay_finite_at_tiny_temperatures() {
    for temperature in [1e-12, 1e-6, 1e-3] {
        let names = vocabulary(temperature).hypotheses(&[1.0, 0.999, 0.0], 3);
        assert_eq!(names.len(), 3);
        assert!(names.iter().all(|(_, s)| s.is_finite()));
        let total: f32 = names.iter().map(|(_, s)| s).sum();
        assert!((total - 1.0).abs() < 1e-4, "scores sum to {total}");
        assert_eq!(names[0].0, "chair");
    }
}

#[test]
fn close_clusters_merge_and_distant_ones_stay() {
    // Two modes of one instance (0.2 apart on the sphere) and an orthogonal instance.
    let angle = 0.2f32;
    let sums = vec![
        vec![10.0, 0.0, 0.0],
        vec![30.0 * angle.cos(), 30.0 * angle.sin(), 0.0],
        vec![0.0, 0.0, 5.0],
    ];
    let merged = merge_close_clusters(sums.clone(), 0.4);
    assert_eq!(merged.len(), 2);
    // The joined centroid is the renormalised member sum: pulled towards the bigger mode.
    let joined = merged.iter().find(|c| c[2].abs() < 1e-6).unwrap();
    let expected_angle = (30.0 * angle.sin()).atan2(10.0 + 30.0 * angle.cos());
    assert!((joined[1].atan2(joined[0]) - expected_angle).abs() < 1e-5);
    assert!(merged
        .iter()
        .any(|c| embedding_distance(c, &[0.0, 0.0, 1.0]) < 1e-6));
    // Zero merge distance keeps HDBSCAN's clusters.
    assert_eq!(merge_close_clusters(sums.clone(), 0.0).len(), 3);
    // Chains join closest pair first until no pair is close: all three at a huge distance.
    assert_eq!(merge_close_clusters(sums, 2.0).len(), 1);
}

#[test]
fn identical_and_empty_clusters_merge_to_finite_centroids() {
    let identical = vec![vec![0.0, 2.0], vec![0.0, 7.0]];
    let merged = merge_close_clusters(identical, 0.4);
    assert_eq!(merged, vec![vec![0.0, 1.0]]);
    // A cluster of zero vectors has a zero sum: its centroid stays zero (1 from every unit
    // centroid), never NaN.
    let with_zero = vec![vec![0.0, 0.0], vec![3.0, 0.0]];
    let merged = merge_close_clusters(with_zero, 0.4);
    assert_eq!(merged.len(), 2);
    assert!(merged.iter().flatten().all(|v| v.is_finite()));
    assert!(merge_close_clusters(Vec::new(), 0.4).is_empty());
}

#[test]
fn grouping_joins_one_instance_split_into_two_modes() {
    // One instance whose embeddings form two tight modes 0.25 apart, and a second instance
    // orthogonal to both: HDBSCAN alone finds three clusters, the merge two.
    let mut points = Vec::new();
    let mut truth = Vec::new();
    let modes: [([f32; 3], u32); 3] = [
        ([1.0, 0.0, 0.0], 0),
        ([0.25f32.cos(), 0.25f32.sin(), 0.0], 0),
        ([0.0, 0.0, 1.0], 1),
    ];
    for (i, (centre, id)) in modes.iter().enumerate() {
        for j in 0..200 {
            let jitter = 0.01 * (((i * 200 + j) as f32 * 0.618).fract() - 0.5);
            points.extend([centre[0] + jitter, centre[1] - jitter, centre[2] + jitter]);
            truth.push(*id);
        }
    }
    let unmerged = GroupingParams {
        merge_distance: 0.0,
        ..GroupingParams::default()
    };
    assert_eq!(group(&points, 3, &unmerged).unwrap().centroids.len(), 3);
    let result = group(&points, 3, &GroupingParams::default()).unwrap();
    assert_eq!(result.centroids.len(), 2);
    assert!(ari(&result.labels, &truth) > 0.99);
    for bad in [f32::NAN, -0.1, f32::INFINITY] {
        let params = GroupingParams {
            merge_distance: bad,
            ..GroupingParams::default()
        };
        assert!(matches!(
            group(&points, 3, &params),
            Err(GroupError::MergeDistance(_))
        ));
    }
}

#[test]
fn a_long_object_named_by_a_name_that_fits_keeps_no_share_for_names_that_cannot_be_that_long() {
    // A table 1.2 m long whose features leave a chair a real share: the table stands, and the
    // chair (never longer than 0.52 m) keeps nothing, so "all the chairs" does not answer it.
    let v = vocabulary(0.05);
    let tableish = [0.85, 0.9, 0.3];
    let plain = v.probabilities(&tableish);
    assert!(plain[0] > 0.2 && plain[1] > plain[0], "{plain:?}");
    let p = v.probabilities_given(&tableish, Some(length_only(1.2)));
    assert_eq!(p[0], 0.0, "{p:?}");
    assert!(
        p[1] > plain[1] && (p.iter().sum::<f32>() - 1.0).abs() < 1e-5,
        "{p:?}"
    );
    assert!(
        (p[2] / p[1] - plain[2] / plain[1]).abs() < 1e-5,
        "structure keeps its share"
    );
    // At a chair's length nothing changes.
    assert_eq!(
        v.probabilities_given(&tableish, Some(length_only(0.5))),
        plain
    );
}

#[test]
fn nothing_the_vocabulary_names_is_longer_than_twice_its_longest_object() {
    // chair (0.52 m at most) and table (1.38 m): nothing of these is 3 m long; a phrase
    // without priors could be anything.
    let v = vocabulary(0.05);
    assert!(!v.admits_no_object(0.5));
    assert!(
        !v.admits_no_object(2.7),
        "a table with a piece of what it touches"
    );
    assert!(v.admits_no_object(3.0));
    assert!(!v.admits_no_object(f64::NAN));
    assert!(!v.admits_no_object(f64::INFINITY));
    let mut unknown = vocabulary(0.05);
    unknown.phrases[0] = "whiteboard".into();
    assert!(!unknown.admits_no_object(30.0));
}
