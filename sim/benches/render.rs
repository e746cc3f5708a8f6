//! Ray-caster speed on the example scene: four 128×96 views, and one 640×480 view (targets on 2
//! cores, issue 3: ≤ 20 ms and ≤ 50 ms); a procedural room's four views; and one 320×240 frame
//! rendered directly, through the simulation with no effects (must cost the same: unused effects
//! cost nothing), and with every effect on.
//!
//! `cargo bench -p groupforward-sim --bench render`

#![allow(clippy::unwrap_used)] // benchmark setup

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use groupforward_sim::procedural::{generate, Split};
use groupforward_sim::render::{render, Pinhole};
use groupforward_sim::scene::{camera_pose, pinhole, SceneFile};
use groupforward_sim::simulation::Simulation;

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
    let room = generate(Split::Benchmark, 0).unwrap();
    let room_scene = room.build().unwrap();
    let room_views: Vec<_> = room
        .robot_poses()
        .unwrap()
        .iter()
        .step_by(6)
        .take(4)
        .map(|p| camera_pose(&room.cameras[0], p))
        .collect();
    group.bench_function("procedural_room_4_views_128x96", |b| {
        b.iter(|| {
            for (rotation, position) in &room_views {
                render(&room_scene, &small, *rotation, *position);
            }
        })
    });
    group.finish();

    let mut group = c.benchmark_group("sim_frame_320x240");
    let clean = Simulation::new(file.clone()).unwrap();
    let office = SceneFile::builtin("office_effects").unwrap();
    let mut office_clean = office.clone();
    office_clean.effects.clear();
    let office_clean = Simulation::new(office_clean).unwrap();
    let office = Simulation::new(office).unwrap();
    let (rotation, position) = camera_pose(camera, &poses[5]);
    group.bench_function("two_chairs_direct_render", |b| {
        b.iter(|| render(&scene, &pinhole(camera), rotation, position))
    });
    group.bench_function("two_chairs_simulation_no_effects", |b| {
        b.iter(|| clean.frame(5))
    });
    group.bench_function("office_no_effects", |b| b.iter(|| office_clean.frame(5)));
    group.bench_function("office_all_ten_effects", |b| b.iter(|| office.frame(5)));
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
