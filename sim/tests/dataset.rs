#![allow(clippy::unwrap_used)]
//! A written dataset is self-consistent: reading back its PNGs and cameras.json, every object
//! pixel's depth, intrinsics and pose put it inside that object's bounds.

use groupforward_sim::dataset::{write_dataset, DatasetOptions};
use groupforward_sim::procedural::Split;

#[test]
fn written_samples_reproject_onto_their_objects() {
    let dir = tempfile::tempdir().unwrap();
    let options = DatasetOptions {
        split: Split::Val,
        samples: 3,
        views: 2,
        width: 48,
        height: 36,
        ..DatasetOptions::default()
    };
    let done = std::sync::atomic::AtomicUsize::new(0);
    let summary = write_dataset(dir.path(), &options, &|n| {
        done.fetch_max(n, std::sync::atomic::Ordering::Relaxed);
    })
    .unwrap();
    assert_eq!(done.into_inner(), 3);
    assert_eq!(summary.views, 6);
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("dataset.json")).unwrap()).unwrap();
    assert_eq!(manifest["split"], "val");
    assert_eq!(manifest["classes"].as_array().unwrap().len(), 16);
    let mut checked = 0;
    for scene in manifest["scenes"].as_array().unwrap() {
        let sample = dir.path().join(scene.as_str().unwrap());
        let cameras: serde_json::Value =
            serde_json::from_slice(&std::fs::read(sample.join("cameras.json")).unwrap()).unwrap();
        let objects = cameras["objects"].as_array().unwrap();
        for view in cameras["views"].as_array().unwrap() {
            let rgb = image::open(sample.join(view["rgb"].as_str().unwrap()))
                .unwrap()
                .to_rgb8();
            assert_eq!(rgb.dimensions(), (48, 36));
            let depth = image::open(sample.join(view["depth"].as_str().unwrap()))
                .unwrap()
                .to_luma16();
            let instance = image::open(sample.join(view["instance"].as_str().unwrap()))
                .unwrap()
                .to_luma16();
            let k: Vec<f64> = serde_json::from_value(view["k"].clone()).unwrap();
            let m: Vec<Vec<f64>> =
                serde_json::from_value(view["world_from_camera"].clone()).unwrap();
            for (x, y, id) in instance.enumerate_pixels().map(|(x, y, p)| (x, y, p.0[0])) {
                if id == 0 {
                    continue;
                }
                let z = f64::from(depth.get_pixel(x, y).0[0]) / 1000.0;
                let c = [
                    (f64::from(x) - k[2]) / k[0] * z,
                    (f64::from(y) - k[5]) / k[4] * z,
                    z,
                ];
                let w: Vec<f64> = (0..3)
                    .map(|r| m[r][0] * c[0] + m[r][1] * c[1] + m[r][2] * c[2] + m[r][3])
                    .collect();
                let object = objects.iter().find(|o| o["instance_id"] == id).unwrap();
                let lo: Vec<f64> = serde_json::from_value(object["bounds_min"].clone()).unwrap();
                let hi: Vec<f64> = serde_json::from_value(object["bounds_max"].clone()).unwrap();
                // Depth is stored in whole millimetres.
                for a in 0..3 {
                    assert!(
                        w[a] > lo[a] - 0.01 && w[a] < hi[a] + 0.01,
                        "pixel ({x},{y}) of {id}"
                    );
                }
                checked += 1;
            }
        }
    }
    assert!(checked > 50, "only {checked} object pixels");
}

#[test]
fn a_dataset_with_effects_draws_them_per_sample_and_says_so() {
    use groupforward_sim::effects::Preset;
    let dir = tempfile::tempdir().unwrap();
    let options = DatasetOptions {
        split: Split::Train,
        samples: 8,
        views: 2,
        width: 48,
        height: 36,
        effects: Some(Preset::Realistic),
        ..DatasetOptions::default()
    };
    write_dataset(dir.path(), &options, &|_| {}).unwrap();
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("dataset.json")).unwrap()).unwrap();
    assert_eq!(manifest["effects"], "realistic");
    // Depth PNGs carry dropout as 0 (what the training reader takes as invalid), in different
    // amounts per sample: some clean, some with holes.
    let mut invalid_fractions = Vec::new();
    for scene in manifest["scenes"].as_array().unwrap() {
        let sample = dir.path().join(scene.as_str().unwrap());
        let cameras: serde_json::Value =
            serde_json::from_slice(&std::fs::read(sample.join("cameras.json")).unwrap()).unwrap();
        let view = &cameras["views"][0];
        let depth = image::open(sample.join(view["depth"].as_str().unwrap()))
            .unwrap()
            .to_luma16();
        assert_eq!(depth.dimensions(), (48, 36));
        let zeros = depth.pixels().filter(|p| p.0[0] == 0).count();
        invalid_fractions.push(zeros as f64 / (48.0 * 36.0));
    }
    assert!(invalid_fractions.contains(&0.0), "{invalid_fractions:?}");
    assert!(
        invalid_fractions.iter().any(|&f| f > 0.01),
        "{invalid_fractions:?}"
    );
    // The draw is the scene's: the same options write the same files.
    let again = tempfile::tempdir().unwrap();
    write_dataset(again.path(), &options, &|_| {}).unwrap();
    let first = manifest["scenes"][0].as_str().unwrap();
    for file in ["view_00_rgb.png", "view_00_depth.png"] {
        assert_eq!(
            std::fs::read(dir.path().join(first).join(file)).unwrap(),
            std::fs::read(again.path().join(first).join(file)).unwrap(),
            "{file}"
        );
    }
}
