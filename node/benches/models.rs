//! Model runner latency by number of views (2, 4, 8) and ONNX Runtime threads (1, 2).
//! - `recon_fixture`: the reconstruction runner on the contract fixture at 128×96 (640×480 inputs):
//!   pre-processing, session call and lifting to Gaussians. The fixture's graph is trivial
//!   arithmetic, so this is the runner's overhead, not a model's compute.
//! - `text_encoder`: one uncached phrase through the int8 MiniLM.
//!
//! `cargo bench -p groupforward --bench models` (needs `make setup` for the ONNX Runtime library)

#![allow(clippy::unwrap_used)] // benchmark setup

use std::path::Path;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use groupforward::frame::{DepthImage, RgbImage};
use groupforward::model::reconstruction::{ReconstructionModel, View};
use groupforward::model::text::TextEncoder;
use groupforward::model::{init_runtime, SessionOptions};
use groupforward::recon::camera::Camera;
use groupforward::recon::Rigid;

fn models(c: &mut Criterion) {
    init_runtime(None).unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    // The fixture at a realistic input size (its graph takes any H and W).
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(
        root.join("models/fixtures/recon_contract.onnx"),
        dir.path().join("recon_contract.onnx"),
    )
    .unwrap();
    let manifest = std::fs::read_to_string(root.join("models/fixtures/recon_contract.toml"))
        .unwrap()
        .replace("input_height = 4", "input_height = 96")
        .replace("input_width = 6", "input_width = 128");
    std::fs::write(dir.path().join("fixture.toml"), manifest).unwrap();

    let rgb = RgbImage {
        width: 640,
        height: 480,
        data: (0..640 * 480 * 3).map(|i| (i % 251) as u8).collect(),
    };
    let depth = DepthImage {
        width: 640,
        height: 480,
        metres: vec![2.0; 640 * 480],
    };
    let camera = Camera::from_fov(640, 480, 1.2).unwrap();

    let mut group = c.benchmark_group("recon_fixture_128x96");
    group.sample_size(20);
    for threads in [1, 2] {
        let options = SessionOptions {
            intra_threads: threads,
            ..SessionOptions::default()
        };
        let mut model =
            ReconstructionModel::load(&dir.path().join("fixture.toml"), &options).unwrap();
        for views in [2, 4, 8] {
            let inputs: Vec<View> = (0..views)
                .map(|i| View {
                    rgb: &rgb,
                    depth: Some(&depth),
                    camera,
                    world_from_camera: Rigid::new(
                        glam::DQuat::IDENTITY,
                        glam::DVec3::new(0.1 * i as f64, 0.0, 0.0),
                    ),
                })
                .collect();
            group.bench_with_input(
                BenchmarkId::new(format!("threads{threads}"), views),
                &views,
                |b, _| {
                    b.iter(|| {
                        let prediction = model.predict(&inputs).unwrap();
                        model.to_gaussians(&prediction, &inputs).unwrap()
                    })
                },
            );
        }
    }
    group.finish();

    let mut group = c.benchmark_group("text_encoder_minilm_int8");
    for threads in [1, 2] {
        let options = SessionOptions {
            intra_threads: threads,
            ..SessionOptions::default()
        };
        let mut encoder =
            TextEncoder::load(&root.join("models/all-MiniLM-L6-v2.toml"), &options).unwrap();
        let mut counter = 0u64;
        group.bench_function(format!("threads{threads}_uncached_phrase"), |b| {
            b.iter(|| {
                counter += 1;
                encoder
                    .embed(&format!("the trash bin near cabinet number {counter}"))
                    .unwrap()
            })
        });
    }
    group.finish();
}

criterion_group!(benches, models);
criterion_main!(benches);
