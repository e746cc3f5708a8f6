#![allow(clippy::unwrap_used)]
//! The Python copy of the node's grouping (`train/gf/grouping.py`, which scores every model in
//! `train/eval_recon.py` and so every ARI figure of the README) against the Rust `group()`, on
//! the same fixed embeddings: the same labels up to a renaming of the clusters, noise included.
//! Runs the project's test venv (`make setup`), whose `hdbscan` package is the reference.

use std::collections::HashMap;

use groupforward::group::hdbscan::{hdbscan, hdbscan_gridded};
use groupforward::group::{group, normalize_rows, GroupingParams};
use groupforward_tests::{root, venv_python};

/// Unit 8-d embeddings: seven tight clusters of different sizes on the sphere, two of them 0.29
/// apart (one instance split in two density modes: the merge step must join them), a small object
/// of 20 (too few for the first pass: the residual pass finds it), one crowded as a trained model
/// crowds an instance (its points share the cells of HDBSCAN's grid), and scattered points far
/// from every cluster (noise by the distance threshold). A fixed LCG keeps them the same
/// everywhere.
fn embeddings() -> Vec<f32> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut uniform = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((state >> 11) as f64 / (1u64 << 53) as f64) as f32
    };
    let unit = |v: Vec<f32>| {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.into_iter().map(|x| x / n).collect::<Vec<f32>>()
    };
    let mut centres: Vec<Vec<f32>> = (0..6)
        .map(|k| {
            unit(
                (0..8)
                    .map(|d| if d == k { 1.0 } else { 0.1 * d as f32 })
                    .collect(),
            )
        })
        .collect();
    let mut twin = centres[0].clone();
    twin[7] += 0.6;
    centres.push(unit(twin));
    centres.push(unit(
        (0..8).map(|d| if d < 2 { -1.0 } else { 0.0 }).collect(),
    ));
    let mut out = Vec::new();
    for (k, centre) in centres.iter().enumerate() {
        let members = if k == 7 { 20 } else { 120 + 60 * k };
        for j in 0..members {
            // The crowded one: a tight core inside a looser halo.
            let jitter = if k == 2 && j % 2 == 0 { 0.0004 } else { 0.03 };
            let point: Vec<f32> = centre
                .iter()
                .map(|c| c + jitter * (uniform() - 0.5))
                .collect();
            out.extend(unit(point));
        }
    }
    for _ in 0..40 {
        out.extend(unit((0..8).map(|_| uniform() - 0.5).collect()));
    }
    out
}

/// One bijection between the two label sets, with noise (-1) mapped to noise.
fn assert_same_partition(rust: &[i32], python: &[i64], what: &str) {
    assert_eq!(python.len(), rust.len(), "{what}");
    let mut forward: HashMap<i32, i64> = HashMap::new();
    let mut backward: HashMap<i64, i32> = HashMap::new();
    for (&r, &p) in rust.iter().zip(python) {
        assert_eq!(
            *forward.entry(r).or_insert(p),
            p,
            "{what}: Rust label {r} is two Python labels"
        );
        assert_eq!(
            *backward.entry(p).or_insert(r),
            r,
            "{what}: Python label {p} is two Rust labels"
        );
    }
    assert_eq!(
        forward.get(&-1),
        Some(&-1),
        "{what}: noise is noise in both"
    );
}

#[test]
fn the_python_grouping_in_train_gives_the_node_s_labels() {
    let points = embeddings();
    // Both at their defaults (the residual pass included): the Python constants are copies.
    let rust = group(&points, 8, &GroupingParams::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("embeddings.f32");
    std::fs::write(
        &file,
        points
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect::<Vec<u8>>(),
    )
    .unwrap();
    let script = format!(
        "import sys, json, numpy as np\n\
         sys.path.insert(0, {train:?})\n\
         from gf.grouping import node_grouping\n\
         e = np.fromfile({file:?}, dtype='<f4').reshape(-1, 8)\n\
         print(json.dumps(node_grouping(e)[0].tolist()))\n",
        train = root().join("train").display().to_string(),
        file = file.display().to_string(),
    );
    let stdout = venv_python(&script);
    let python_labels: Vec<i64> = serde_json::from_slice(&stdout).unwrap();
    assert_same_partition(&rust.labels, &python_labels, "grouping");
    // The node clusters a grid of the embeddings, the Python copy every embedding: the fixture's
    // crowded instance is where the two first HDBSCANs differ, and the groupings still agree.
    let mut unit = points.clone();
    normalize_rows(&mut unit, 8);
    let defaults = GroupingParams::default();
    let on_grid =
        hdbscan_gridded(&unit, 8, &defaults.hdbscan, f64::from(defaults.resolution)).unwrap();
    let every_point = hdbscan(&unit, 8, &defaults.hdbscan).unwrap();
    assert_ne!(on_grid.labels, every_point.labels, "the grid matters here");
    // The fixture exercises what it claims: six instances after the twin modes merge, a seventh
    // from the residual pass, and noise.
    assert_eq!(
        rust.centroids.len(),
        7,
        "{} instances",
        rust.centroids.len()
    );
    let noise = rust.labels.iter().filter(|&&l| l < 0).count();
    assert!((20..=40).contains(&noise), "{noise} noise points");
}
