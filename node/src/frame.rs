//! The data that flows between stages: decoded images, synced camera frames, keyframes and what
//! a window pass hands to fusion. Plain data over the geometric core ([`crate::recon`]); every
//! stage above imports it, it imports no stage.

use glam::{DVec2, Vec3};

use crate::recon::camera::Camera;
use crate::recon::gaussians::Gaussians;
use crate::recon::Rigid;

/// An 8-bit RGB image, row-major, tightly packed.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

/// Metric depth, row-major; invalid pixels are NaN.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    pub width: u32,
    pub height: u32,
    pub metres: Vec<f32>,
}

/// One camera frame with everything later stages need.
#[derive(Debug, Clone, PartialEq)]
pub struct SyncedFrame {
    /// Name of the configured camera.
    pub camera_name: String,
    pub stamp_nanos: i64,
    /// The image's optical frame (REP-103: z forward, x right, y down).
    pub frame_id: String,
    pub rgb: RgbImage,
    pub depth: Option<DepthImage>,
    /// Validated intrinsics and distortion from the latest CameraInfo.
    pub camera: Camera,
    pub world_from_camera: Rigid,
}

/// One instance of a window pass.
#[derive(Debug, Clone, PartialEq)]
pub struct WindowInstance {
    pub gaussians: Gaussians,
    /// Semantic prototype f_k (masked mean of the semantic features, §5.5).
    pub prototype: Vec<f32>,
    /// Pixels the prototype averages (its weight when merged).
    pub support: usize,
}

/// A camera view kept with the map (a keyframe).
#[derive(Debug, Clone, PartialEq)]
pub struct Keyframe {
    pub stamp_nanos: i64,
    pub camera: Camera,
    pub world_from_camera: Rigid,
}

/// A view's depth as its sensor measured it, at the sensor's resolution: kept for the newest
/// views so answers' masks can be cut by it ([`crate::refer::masks`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredDepth {
    /// The view, with the sensor's camera (its resolution and distortion).
    pub keyframe: Keyframe,
    /// Metres along the optical axis, row-major; NaN or <= 0 where there is no reading.
    pub depth: Vec<f32>,
    /// Its range noise (σ at 1 m), as measured for fusion.
    pub noise_at_1m: Option<f32>,
    /// [`MeasuredDepth::world_points`], unprojected on first use: every answer's mask in this
    /// view reads them, and they depend on the view alone, not on the map.
    world_points: std::sync::OnceLock<Vec<Vec3>>,
}

impl MeasuredDepth {
    pub fn new(keyframe: Keyframe, depth: Vec<f32>, noise_at_1m: Option<f32>) -> Self {
        Self {
            keyframe,
            depth,
            noise_at_1m,
            world_points: std::sync::OnceLock::new(),
        }
    }

    /// Each pixel's reading as a world point ([`world_points`]).
    pub fn world_points(&self) -> &[Vec3] {
        self.world_points
            .get_or_init(|| world_points(&self.keyframe, &self.depth))
    }
}

/// Per pixel of `keyframe` (row-major, its resolution), the point its z-depth in `depth`
/// measured, in the world frame, at the integer pixel coordinates the model's Gaussians were
/// lifted at; NaN where there is no reading (NaN, <= 0, or past the end of `depth`).
pub fn world_points(keyframe: &Keyframe, depth: &[f32]) -> Vec<Vec3> {
    let w = keyframe.camera.width as usize;
    let h = keyframe.camera.height as usize;
    (0..w * h)
        .map(|p| match depth.get(p) {
            Some(&d) if d.is_finite() && d > 0.0 => {
                let pixel = DVec2::new((p % w) as f64, (p / w) as f64);
                keyframe
                    .world_from_camera
                    .transform_point(keyframe.camera.unproject(pixel, f64::from(d)))
                    .as_vec3()
            }
            _ => Vec3::NAN,
        })
        .collect()
}

/// A window view as fusion sees it: the keyframe and the depth the window observed there (sensor
/// or rendered), used to decide which persistent instances it should have seen.
#[derive(Debug, Clone, PartialEq)]
pub struct WindowView {
    pub keyframe: Keyframe,
    pub depth: Vec<f32>,
    /// The sensor's depth noise at 1 m (m), measured on the view's full-resolution depth image
    /// ([`crate::recon::depth_noise`]); `None` without depth or where it is too small to measure.
    pub depth_noise_at_1m: Option<f32>,
}

/// Resample an image taken by a distorted `camera` into its undistorted pinhole camera
/// ([`Camera::undistorted`]; bilinear, black outside).
pub fn undistort_image(camera: &Camera, image: &RgbImage) -> RgbImage {
    let (w, h) = (image.width as usize, image.height as usize);
    let mut data = vec![0u8; w * h * 3];
    if camera.distortion.is_zero() {
        data.copy_from_slice(&image.data[..w * h * 3]);
    } else {
        for v in 0..h {
            for u in 0..w {
                let n = DVec2::new(
                    (u as f64 - camera.cx) / camera.fx,
                    (v as f64 - camera.cy) / camera.fy,
                );
                let d = camera.distortion.distort(n);
                let src = DVec2::new(camera.fx * d.x + camera.cx, camera.fy * d.y + camera.cy);
                if let Some(rgb) = bilinear(image, src) {
                    data[(v * w + u) * 3..][..3].copy_from_slice(&rgb);
                }
            }
        }
    }
    RgbImage {
        width: image.width,
        height: image.height,
        data,
    }
}

fn bilinear(image: &RgbImage, p: DVec2) -> Option<[u8; 3]> {
    let (w, h) = (image.width as usize, image.height as usize);
    if !(p.x >= 0.0 && p.y >= 0.0 && p.x <= (w - 1) as f64 && p.y <= (h - 1) as f64) {
        return None;
    }
    let (x0, y0) = (p.x.floor() as usize, p.y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (p.x - x0 as f64, p.y - y0 as f64);
    let at = |x: usize, y: usize, c: usize| f64::from(image.data[(y * w + x) * 3 + c]);
    let mut out = [0u8; 3];
    for (c, value) in out.iter_mut().enumerate() {
        let top = at(x0, y0, c) * (1.0 - fx) + at(x1, y0, c) * fx;
        let bottom = at(x0, y1, c) * (1.0 - fx) + at(x1, y1, c) * fx;
        *value = (top * (1.0 - fy) + bottom * fy).round().clamp(0.0, 255.0) as u8;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::camera::distorted_test_camera as distorted;

    #[test]
    fn undistorting_an_undistorted_camera_is_identity() {
        let camera = Camera::from_fov(4, 3, 1.0).unwrap();
        let image = RgbImage {
            width: 4,
            height: 3,
            data: (0..36).collect(),
        };
        assert_eq!(undistort_image(&camera, &image), image);
        let warped = undistort_image(
            &distorted(),
            &RgbImage {
                width: 640,
                height: 480,
                data: vec![200; 640 * 480 * 3],
            },
        );
        // The centre maps onto itself; the corners fall outside the distorted image.
        assert_eq!(warped.data[(240 * 640 + 320) * 3], 200);
    }
}
