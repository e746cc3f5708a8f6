//! Ray-caster speed on the example scene: four 128×96 views, and one 640×480 view.
//! Targets on 2 cores (issue 3): ≤ 20 ms and ≤ 50 ms.
//!
//! `cargo bench -p groupforward-sim --bench render`

#![allow(clippy::unwrap_used)] // benchmark setup

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use groupforward_sim::render::{render, Pinhole};
use groupforward_sim::scene::{camera_pose, SceneFile};

fn bench(c: &mut Criterion) {
    let file =
        SceneFile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/two_chairs.toml"))
            .unwrap();
    let scene = file.build().unwrap();
    let poses = file.robot_poses().unwrap();
    let camera = &file.cameras[0];
    let views: Vec<_> = poses
        .iter()
        .step_by(10)
        .take(4)
        .map(|p| camera_pose(camera, p))
        .collect();
    let small = Pinhole::from_fov(128, 96, camera.fov_x_deg.to_radians());
    let large = Pinhole::from_fov(640, 480, camera.fov_x_deg.to_radians());
    let mut group = c.benchmark_group("sim_render_two_chairs");
    group.bench_function("4_views_128x96", |b| {
        b.iter(|| {
            for (rotation, position) in &views {
                render(&scene, &small, *rotation, *position);
            }
        })
    });
    group.bench_function("1_view_640x480", |b| {
        b.iter(|| render(&scene, &large, views[0].0, views[0].1))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
