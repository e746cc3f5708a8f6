//! Rasterizer speed: 100k Gaussians at 640×480 (RGB + depth), four 128×96 views of pixel-aligned
//! Gaussians, and the tile path against the brute-force reference on the same small scene (their
//! ratio is the figure to report; absolute times depend on the machine).
//!
//! `cargo bench -p groupforward --bench raster`

#![allow(clippy::unwrap_used)] // benchmark setup

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::{DQuat, DVec3, Quat, Vec3};
use groupforward::recon::camera::Camera;
use groupforward::recon::gaussians::{lift, Gaussians, PixelAligned};
use groupforward::recon::raster::{reference, render, RasterSettings};
use groupforward::recon::Rigid;

struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }

    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next()
    }
}

/// Gaussians scattered through the frustum of a camera at the origin (depth 1–8 m), sized like a
/// pixel-aligned reconstruction's: a standard deviation of 0.5–1.5 pixels in `camera`.
fn random_scene(n: usize, seed: u64, camera: &Camera) -> (Gaussians, Vec<f32>) {
    let mut rng = Lcg(seed);
    let mut g = Gaussians::with_dims(0, 0);
    let mut rgb = Vec::with_capacity(n * 3);
    for _ in 0..n {
        let z = rng.range(1.0, 8.0);
        let mean = Vec3::new(rng.range(-0.6, 0.6) * z, rng.range(-0.45, 0.45) * z, z);
        let s = z * rng.range(0.5, 1.5) / camera.fx as f32;
        let scale = Vec3::new(s, s * rng.range(0.3, 1.0), s * 0.2);
        let rotation = Quat::from_xyzw(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            1.0,
        )
        .normalize();
        let color = Vec3::new(rng.next(), rng.next(), rng.next());
        g.push(mean, rng.range(0.3, 1.0), scale, rotation, color, &[], &[]);
        rgb.extend_from_slice(&color.to_array());
    }
    (g, rgb)
}

/// Four views of a room-like depth map (a tilted floor and a back wall), lifted pixel-aligned.
fn pixel_aligned_views(width: usize, height: usize) -> (Gaussians, Vec<f32>, Vec<Rigid>, Camera) {
    let camera = Camera::from_fov(width as u32, height as u32, 1.2).unwrap();
    let n = width * height;
    let depth: Vec<f32> = (0..n)
        .map(|i| {
            let (u, v) = ((i % width) as f32, (i / width) as f32);
            let wall = 4.0 + 0.3 * (u / width as f32);
            let floor = 1.2 * height as f32 / (v - height as f32 * 0.45).max(1.0);
            wall.min(floor.max(0.5))
        })
        .collect();
    let opacity = vec![0.9; n];
    let scale = vec![[0.7, 0.7, 0.1]; n];
    let rotation = vec![[0.0, 0.0, 0.0, 1.0]; n];
    let color: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            [
                (i % width) as f32 / width as f32,
                (i / width) as f32 / height as f32,
                0.5,
            ]
        })
        .collect();
    let mut all = Gaussians::with_dims(0, 0);
    let mut poses = Vec::new();
    for view in 0..4 {
        let world_from_camera = Rigid::new(
            DQuat::from_rotation_y(0.15 * view as f64),
            DVec3::new(0.2 * view as f64, 0.0, 0.0),
        );
        let prediction = PixelAligned {
            width,
            height,
            depth: &depth,
            opacity: &opacity,
            scale: &scale,
            rotation: &rotation,
            color: &color,
            embedding_dim: 0,
            embedding: &[],
        };
        all.extend(&lift(&prediction, &camera, &world_from_camera).unwrap());
        poses.push(world_from_camera);
    }
    let rgb = all.colors.iter().flat_map(|c| c.to_array()).collect();
    (all, rgb, poses, camera)
}

fn raster(c: &mut Criterion) {
    let settings = RasterSettings::default();

    let camera = Camera::from_fov(640, 480, 1.2).unwrap();
    let (g, rgb) = random_scene(100_000, 1, &camera);
    let mut group = c.benchmark_group("raster");
    group.sample_size(20);
    group.measurement_time(Duration::from_secs(10));
    group.throughput(Throughput::Elements(1));
    group.bench_function("100k_gaussians_640x480_rgb_depth", |b| {
        b.iter(|| render(&g, &rgb, 3, &camera, &Rigid::IDENTITY, &settings).unwrap())
    });

    let (views, view_rgb, poses, view_camera) = pixel_aligned_views(128, 96);
    group.throughput(Throughput::Elements(4));
    group.bench_function("4_views_128x96_pixel_aligned_49k", |b| {
        b.iter(|| {
            for pose in &poses {
                render(
                    &views,
                    &view_rgb,
                    3,
                    &view_camera,
                    &pose.inverse(),
                    &settings,
                )
                .unwrap();
            }
        })
    });

    // Same small scene through both paths: the ratio of these two is the speed-up.
    let small_camera = Camera::from_fov(128, 96, 1.2).unwrap();
    let (small, small_rgb) = random_scene(2_000, 2, &small_camera);
    group.throughput(Throughput::Elements(1));
    group.bench_function("2k_gaussians_128x96_tile", |b| {
        b.iter(|| {
            render(
                &small,
                &small_rgb,
                3,
                &small_camera,
                &Rigid::IDENTITY,
                &settings,
            )
            .unwrap()
        })
    });
    group.sample_size(10);
    group.bench_function("2k_gaussians_128x96_brute_force_reference", |b| {
        b.iter(|| {
            reference::render(
                &small,
                &small_rgb,
                3,
                &small_camera,
                &Rigid::IDENTITY,
                &settings,
            )
            .unwrap()
        })
    });
    group.finish();
}

criterion_group!(benches, raster);
criterion_main!(benches);
