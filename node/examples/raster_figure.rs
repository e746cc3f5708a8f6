//! Render a small Gaussian scene with the tile rasterizer and the brute-force reference, and write
//! them side by side with their difference (×1000) to `node/doc/raster_vs_reference.png`.
//!
//! `cargo run -p groupforward --example raster_figure`

use anyhow::Result;
use glam::{Quat, Vec3};
use groupforward::recon::camera::Camera;
use groupforward::recon::gaussians::Gaussians;
use groupforward::recon::raster::{reference, render, RasterSettings};
use groupforward::recon::Rigid;

fn main() -> Result<()> {
    let camera = Camera::from_fov(160, 120, 1.0)?;
    let mut g = Gaussians::with_dims(0, 0);
    let mut rgb = Vec::new();
    // A ring of coloured, elongated Gaussians around a large translucent one.
    g.push(
        Vec3::new(0.0, 0.0, 4.0),
        0.4,
        Vec3::new(0.8, 0.5, 0.1),
        Quat::IDENTITY,
        Vec3::ONE,
        &[],
        &[],
    );
    rgb.extend_from_slice(&[0.9, 0.9, 0.9]);
    for i in 0..24 {
        let angle = i as f32 / 24.0 * std::f32::consts::TAU;
        let mean = Vec3::new(
            1.2 * angle.cos(),
            0.8 * angle.sin(),
            3.0 + 0.5 * (2.0 * angle).sin(),
        );
        let rotation = Quat::from_rotation_z(angle);
        g.push(
            mean,
            0.85,
            Vec3::new(0.25, 0.05, 0.05),
            rotation,
            Vec3::ONE,
            &[],
            &[],
        );
        rgb.extend_from_slice(&[0.5 + 0.5 * angle.cos(), 0.5 + 0.5 * angle.sin(), 0.3]);
    }
    let settings = RasterSettings::default();
    let fast = render(&g, &rgb, 3, &camera, &Rigid::IDENTITY, &settings)?;
    let slow = reference::render(&g, &rgb, 3, &camera, &Rigid::IDENTITY, &settings)?;
    let (w, h) = (fast.width, fast.height);
    let mut image = image::RgbImage::new(3 * w as u32 + 8, h as u32);
    let to_u8 = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let mut max_diff = 0.0f32;
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let a = &fast.features[p * 3..p * 3 + 3];
            let b = &slow.features[p * 3..p * 3 + 3];
            let diff: Vec<f32> = a.iter().zip(b).map(|(a, b)| (a - b).abs()).collect();
            max_diff = diff.iter().fold(max_diff, |m, d| m.max(*d));
            image.put_pixel(
                x as u32,
                y as u32,
                image::Rgb([to_u8(a[0]), to_u8(a[1]), to_u8(a[2])]),
            );
            image.put_pixel(
                (w + 4 + x) as u32,
                y as u32,
                image::Rgb([to_u8(b[0]), to_u8(b[1]), to_u8(b[2])]),
            );
            let d = diff.iter().fold(0.0f32, |m, v| m.max(*v)) * 1000.0;
            image.put_pixel((2 * w + 8 + x) as u32, y as u32, image::Rgb([to_u8(d); 3]));
        }
    }
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("doc/raster_vs_reference.png");
    image.save(&path)?;
    println!(
        "wrote {} (tile | brute force | |difference| x 1000); max difference {max_diff:.2e}",
        path.display()
    );
    Ok(())
}
