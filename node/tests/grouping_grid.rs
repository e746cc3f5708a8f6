#![allow(clippy::unwrap_used)]
//! HDBSCAN over grid cells (`hdbscan_gridded`, the grouping's default): the points of one cell
//! count as one point at their mean with their number as its weight. Finer than every gap it is
//! the exact clustering; a weight counts as the repeated points it stands for; and on embeddings
//! crowded around their instances' centres the grouping assigns what the exact one assigns.

use groupforward::group::blobs::blobs;
use groupforward::group::hdbscan::{hdbscan, hdbscan_gridded, HdbscanError, HdbscanParams};
use groupforward::group::{group, GroupError, GroupingParams};
use groupforward::recon::metrics::adjusted_rand_index;

fn params(min_cluster_size: usize, min_samples: usize) -> HdbscanParams {
    HdbscanParams {
        min_cluster_size,
        min_samples,
        allow_single_cluster: false,
    }
}

/// The same clusters up to their numbering, and the same noise.
fn same_partition(a: &[i32], b: &[i32]) -> bool {
    let mut forward = std::collections::HashMap::new();
    let mut backward = std::collections::HashMap::new();
    a.len() == b.len()
        && a.iter().zip(b).all(|(&x, &y)| {
            (x < 0) == (y < 0)
                && *forward.entry(x).or_insert(y) == y
                && *backward.entry(y).or_insert(x) == x
        })
}

#[test]
fn a_resolution_finer_than_any_gap_gives_the_exact_clustering() {
    let (points, _) = blobs(3000, 8, 6, 1.0, 1);
    let exact = hdbscan(&points, 8, &params(60, 10)).unwrap();
    let gridded = hdbscan_gridded(&points, 8, &params(60, 10), 1e-9).unwrap();
    assert_eq!(gridded.n_clusters, exact.n_clusters);
    assert!(same_partition(&gridded.labels, &exact.labels));
}

#[test]
fn a_cell_s_weight_counts_as_the_repeated_points_it_stands_for() {
    // Each point one to four times: the exact clustering sees the copies, the grid one point
    // weighted by their number. Overlapping blobs, so that core distances and stabilities decide.
    let (points, _) = blobs(800, 8, 5, 2.5, 4);
    let repeated: Vec<f32> = points
        .chunks(8)
        .enumerate()
        .flat_map(|(i, row)| std::iter::repeat_n(row, 1 + i % 4).flatten().copied())
        .collect();
    for (min_cluster_size, min_samples) in [(60, 10), (30, 4), (90, 17)] {
        let p = params(min_cluster_size, min_samples);
        let exact = hdbscan(&repeated, 8, &p).unwrap();
        let gridded = hdbscan_gridded(&repeated, 8, &p, 1e-9).unwrap();
        assert_eq!(gridded.n_clusters, exact.n_clusters, "{p:?}");
        assert!(same_partition(&gridded.labels, &exact.labels), "{p:?}");
        assert!(
            exact.n_clusters >= 2,
            "{p:?}: a case with clusters to agree on"
        );
    }
}

#[test]
fn all_identical_embeddings_on_the_grid_are_one_cluster_or_noise_never_nan() {
    let points = vec![0.25f32; 200 * 8];
    let strict = hdbscan_gridded(&points, 8, &params(20, 5), 0.005).unwrap();
    assert_eq!(strict.n_clusters, 0);
    assert!(strict.labels.iter().all(|l| *l == -1));
    let single = HdbscanParams {
        allow_single_cluster: true,
        ..params(20, 5)
    };
    let one = hdbscan_gridded(&points, 8, &single, 0.005).unwrap();
    assert_eq!(one.n_clusters, 1);
    assert!(one.labels.iter().all(|l| *l == 0));
    // Two cells, one point each, fewer than a cluster: noise.
    let pair = [0.0f32, 0.0, 1.0, 1.0];
    let two = hdbscan_gridded(&pair, 2, &single, 0.005).unwrap();
    assert_eq!(two.labels, vec![-1, -1]);
}

#[test]
fn a_resolution_that_is_not_finite_and_positive_is_refused() {
    let (points, _) = blobs(200, 8, 2, 1.0, 5);
    for bad in [0.0, -0.01, f64::NAN, f64::INFINITY] {
        let refused = hdbscan_gridded(&points, 8, &params(20, 5), bad);
        assert!(matches!(refused, Err(HdbscanError::Resolution(_))), "{bad}");
    }
    let nan = GroupingParams {
        resolution: f32::NAN,
        ..GroupingParams::default()
    };
    assert!(matches!(
        group(&points, 8, &nan),
        Err(GroupError::Hdbscan(HdbscanError::Resolution(_)))
    ));
    let exact = GroupingParams {
        resolution: 0.0,
        ..GroupingParams::default()
    };
    assert!(group(&points, 8, &exact).is_ok());
}

/// Unit 8-d embeddings crowded around `instances` centres (jitter well under the grid's 0.005 in
/// each instance's core, wider at its edge) plus scattered ones, as a trained model embeds a
/// window: most points share a cell with others.
fn crowded_embeddings(instances: usize, seed: u64) -> Vec<f32> {
    let (centres, _) = blobs(instances, 8, instances, 1.0, seed);
    let (jitter, _) = blobs(instances * 400, 8, 1, 1.0, seed + 1);
    let mut out = Vec::new();
    let unit = |v: Vec<f32>| {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.into_iter().map(|x| x / n).collect::<Vec<f32>>()
    };
    for (k, centre) in centres.chunks(8).enumerate() {
        for (j, noise) in jitter
            .chunks(8)
            .skip(k * 400)
            .take(100 + 60 * k)
            .enumerate()
        {
            let spread = if j % 5 == 0 { 0.02 } else { 0.0005 };
            let point = centre
                .iter()
                .zip(noise)
                .map(|(c, e)| c / 10.0 + spread * (e - noise[0]))
                .collect();
            out.extend(unit(point));
        }
    }
    let (scattered, _) = blobs(60, 8, 60, 3.0, seed + 2);
    for row in scattered.chunks(8) {
        out.extend(unit(row.to_vec()));
    }
    out
}

#[test]
fn grouping_on_the_grid_assigns_crowded_embeddings_as_the_exact_grouping_does() {
    for seed in [11, 12, 13] {
        let points = crowded_embeddings(6, seed);
        let gridded = group(&points, 8, &GroupingParams::default()).unwrap();
        let exact = group(
            &points,
            8,
            &GroupingParams {
                resolution: 0.0,
                ..GroupingParams::default()
            },
        )
        .unwrap();
        // Centroids come from slightly different cluster cores: a scattered embedding near the
        // noise distance may go either way, the instances may be numbered differently.
        let as_truth = |labels: &[i32]| labels.iter().map(|&l| (l + 1) as u32).collect::<Vec<_>>();
        let agreement =
            adjusted_rand_index(&as_truth(&gridded.labels), &as_truth(&exact.labels)).unwrap();
        assert!(agreement > 0.99, "seed {seed}: ARI {agreement}");
        let instances = |labels: &[i32]| {
            let mut kept: Vec<i32> = labels.iter().copied().filter(|&l| l >= 0).collect();
            kept.sort_unstable();
            kept.dedup();
            kept.len()
        };
        assert_eq!(instances(&gridded.labels), 6, "seed {seed}");
        assert_eq!(instances(&exact.labels), 6, "seed {seed}");
    }
}

#[test]
fn a_cell_that_weighs_a_cluster_alone_is_a_cluster_with_all_its_points() {
    // Two instances whose embeddings each fall in one cell (a model that embeds an instance
    // exactly), and a few scattered ones.
    let mut points = Vec::new();
    for _ in 0..50 {
        points.extend([0.5f32, 0.5, 0.0, 0.0]);
    }
    for _ in 0..70 {
        points.extend([-0.5f32, 0.0, 0.5, 0.0]);
    }
    let (scattered, _) = blobs(5, 4, 5, 3.0, 7);
    points.extend(scattered);
    let p = params(30, 10);
    let gridded = hdbscan_gridded(&points, 4, &p, 0.005).unwrap();
    assert_eq!(gridded.n_clusters, 2);
    assert!(gridded.labels[..50]
        .iter()
        .all(|&l| l == gridded.labels[0] && l >= 0));
    assert!(gridded.labels[50..120]
        .iter()
        .all(|&l| l == gridded.labels[50] && l >= 0));
    assert_ne!(gridded.labels[0], gridded.labels[50]);
    let exact = hdbscan(&points, 4, &p).unwrap();
    assert!(same_partition(&gridded.labels, &exact.labels));
}
