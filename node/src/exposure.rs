//! Exposure compensation of keyframes: a camera's auto-exposure hunts, so one surface comes in
//! brighter in one view than in the next. The models were trained at one fixed exposure and take a
//! brightness change for a change of object: cross-view embeddings stop agreeing and names drift
//! (`eval map --effects realistic`: exposure hunting alone costs about 5 points of recall@0.25
//! and 9 of precision on benchmark 0-9).
//!
//! Each new keyframe's gain is measured against the camera's previous (already compensated)
//! keyframe on the surfaces both see: a valid-depth pixel of the new frame is moved through
//! both poses into the previous frame and kept when the previous frame's depth agrees (not
//! occluded); the gain is the median of the colour ratios of those pixels (robust to sensor noise,
//! blur at edges and the odd mismatch). Gains chain from keyframe to keyframe, so the estimate
//! is relative to the camera's first keyframe; a slow running mean of the chained log-gain is the
//! reference instead, so a first frame caught at the top of a hunt does not set every later image
//! too dark, and the chain's small errors do not accumulate. Each keyframe's colour is then divided
//! by its gain over that reference. Without enough shared surface (a jump, no depth) the gain is
//! taken as unchanged.

use glam::DVec2;

use crate::frame::SyncedFrame;

/// Pixels sampled per row and column of the new frame's depth image.
const SAMPLE_GRID: usize = 64;
/// Shared surface pixels needed to measure a gain.
const MIN_SHARED_PIXELS: usize = 200;
/// Pixels with any channel at or above this are clipped by the sensor: their ratio says nothing.
const CLIPPED: u8 = 250;
/// Pixels darker than this (sum of channels) are mostly read noise.
const MIN_BRIGHTNESS: u32 = 60;
/// A reprojected point is the surface the previous frame saw when their depths agree within this
/// fraction (plus `DEPTH_AGREEMENT_M`).
const DEPTH_AGREEMENT_FRACTION: f64 = 0.03;
const DEPTH_AGREEMENT_M: f64 = 0.02;
/// Time constant of the running mean that anchors the gains (seconds): several periods of a hunting
/// auto-exposure, short against a change of lighting a robot drives into.
const REFERENCE_TIME_CONSTANT_SECS: f64 = 20.0;
/// Corrections this small are not applied (sensor noise of the estimate).
const MIN_CORRECTION: f64 = 0.005;
/// A ratio beyond this (about 3x either way) is a measurement gone wrong, not an exposure.
const MAX_LOG_GAIN: f64 = 1.1;

/// One camera's exposure state across its keyframes.
#[derive(Debug, Default, Clone)]
pub struct ExposureTracker {
    /// Log-gain of the latest keyframe relative to the camera's first one.
    chained: f64,
    /// Running mean of `chained`: the reference the frames are brought to.
    reference: f64,
    /// Log-gain the latest keyframe's colour was divided by.
    applied: f64,
    last_stamp_nanos: Option<i64>,
}

/// What compensating one keyframe did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Compensation {
    /// The gain the frame was divided by (1 = untouched).
    pub gain: f64,
    /// Shared surface pixels the step from the previous keyframe was measured on (0: none).
    pub shared_pixels: usize,
}

impl ExposureTracker {
    /// Bring `frame`'s colour to the camera's reference exposure, measured against `previous`,
    /// the camera's previous keyframe as it was stored (already compensated).
    pub fn compensate(
        &mut self,
        frame: &mut SyncedFrame,
        previous: Option<&SyncedFrame>,
    ) -> Compensation {
        let step = previous.and_then(|p| log_gain_between(p, frame));
        let shared_pixels = step.map_or(0, |(_, n)| n);
        match (self.last_stamp_nanos, step) {
            (None, _) => *self = Self::default(),
            // The step is measured against the previous frame's stored colour, which was divided
            // by its applied gain.
            (Some(_), Some((step, _))) => self.chained += step - self.applied,
            // Unmeasured: the exposure is taken as unchanged.
            (Some(_), None) => {}
        }
        if let Some(last) = self.last_stamp_nanos {
            let dt = ((frame.stamp_nanos - last) as f64 / 1e9).max(0.0);
            let alpha = 1.0 - (-dt / REFERENCE_TIME_CONSTANT_SECS).exp();
            self.reference += alpha * (self.chained - self.reference);
        }
        self.last_stamp_nanos = Some(frame.stamp_nanos);
        let applied = self.chained - self.reference;
        if applied.abs() < MIN_CORRECTION || !applied.is_finite() {
            self.applied = 0.0;
            return Compensation {
                gain: 1.0,
                shared_pixels,
            };
        }
        self.applied = applied;
        let gain = applied.exp();
        let scale = (1.0 / gain) as f32;
        for v in &mut frame.rgb.data {
            *v = (f32::from(*v) * scale).round().clamp(0.0, 255.0) as u8;
        }
        Compensation {
            gain,
            shared_pixels,
        }
    }
}

/// Median log of `next`'s colour over `previous`'s on the surface both see, with how many pixels
/// it was measured on; `None` without depth or enough shared surface.
fn log_gain_between(previous: &SyncedFrame, next: &SyncedFrame) -> Option<(f64, usize)> {
    let depth = next.depth.as_ref()?;
    let previous_depth = previous.depth.as_ref()?;
    let (dw, dh) = (depth.width as usize, depth.height as usize);
    let (pw, ph) = (
        previous_depth.width as usize,
        previous_depth.height as usize,
    );
    if dw == 0 || dh == 0 || pw == 0 || ph == 0 {
        return None;
    }
    let previous_from_next = previous
        .world_from_camera
        .inverse()
        .compose(&next.world_from_camera);
    let step_x = (dw / SAMPLE_GRID).max(1);
    let step_y = (dh / SAMPLE_GRID).max(1);
    let mut ratios = Vec::with_capacity(SAMPLE_GRID * SAMPLE_GRID);
    for y in (step_y / 2..dh).step_by(step_y) {
        for x in (step_x / 2..dw).step_by(step_x) {
            let z = f64::from(depth.metres[y * dw + x]);
            if !(z.is_finite() && z > 0.0) {
                continue;
            }
            let pixel = depth_to_camera_pixel(x, y, dw, dh, &next.camera);
            let point = previous_from_next.transform_point(next.camera.unproject(pixel, z));
            let Some(seen) = previous.camera.project(point) else {
                continue;
            };
            let Some((px, py)) = depth_pixel(seen, pw, ph, &previous.camera) else {
                continue;
            };
            let previous_z = f64::from(previous_depth.metres[py * pw + px]);
            if !(previous_z.is_finite()
                && (previous_z - point.z).abs()
                    <= DEPTH_AGREEMENT_FRACTION * point.z + DEPTH_AGREEMENT_M)
            {
                continue;
            }
            let (Some(now), Some(before)) = (brightness(next, pixel), brightness(previous, seen))
            else {
                continue;
            };
            ratios.push((f64::from(now) / f64::from(before)).ln());
        }
    }
    if ratios.len() < MIN_SHARED_PIXELS {
        return None;
    }
    let middle = ratios.len() / 2;
    let (_, median, _) = ratios.select_nth_unstable_by(middle, f64::total_cmp);
    let median = *median;
    (median.abs() <= MAX_LOG_GAIN).then_some((median, ratios.len()))
}

/// The colour-image pixel (camera coordinates) at the centre of depth pixel `(x, y)`: depth is
/// registered to the colour camera, possibly at another resolution.
fn depth_to_camera_pixel(
    x: usize,
    y: usize,
    dw: usize,
    dh: usize,
    camera: &crate::recon::camera::Camera,
) -> DVec2 {
    DVec2::new(
        (x as f64 + 0.5) * f64::from(camera.width) / dw as f64 - 0.5,
        (y as f64 + 0.5) * f64::from(camera.height) / dh as f64 - 0.5,
    )
}

/// The depth pixel under a camera pixel, if inside the image.
fn depth_pixel(
    pixel: DVec2,
    dw: usize,
    dh: usize,
    camera: &crate::recon::camera::Camera,
) -> Option<(usize, usize)> {
    let x = ((pixel.x + 0.5) * dw as f64 / f64::from(camera.width)).floor();
    let y = ((pixel.y + 0.5) * dh as f64 / f64::from(camera.height)).floor();
    (x >= 0.0 && y >= 0.0 && x < dw as f64 && y < dh as f64).then_some((x as usize, y as usize))
}

/// Sum of the channels at the nearest colour pixel, `None` when clipped, too dark or outside.
fn brightness(frame: &SyncedFrame, pixel: DVec2) -> Option<u32> {
    let (w, h) = (frame.rgb.width as usize, frame.rgb.height as usize);
    let x = pixel.x.round();
    let y = pixel.y.round();
    if !(x >= 0.0 && y >= 0.0 && x < w as f64 && y < h as f64) {
        return None;
    }
    let at = (y as usize * w + x as usize) * 3;
    let rgb = frame.rgb.data.get(at..at + 3)?;
    if rgb.iter().any(|&c| c >= CLIPPED) {
        return None;
    }
    let sum = rgb.iter().map(|&c| u32::from(c)).sum::<u32>();
    (sum >= MIN_BRIGHTNESS).then_some(sum)
}

#[cfg(test)]
mod tests {
    use glam::{DQuat, DVec3};

    use super::*;
    use crate::frame::{DepthImage, RgbImage};
    use crate::recon::camera::Camera;
    use crate::recon::Rigid;

    const WALL_Z: f64 = 2.0;

    /// A textured wall 2 m in front of a camera at `x` (metres), its colour times `gain`, taken at
    /// `secs`.
    fn frame(x: f64, gain: f64, secs: f64, with_depth: bool) -> SyncedFrame {
        let camera = Camera::from_fov(64, 48, 1.2).unwrap_or_else(|e| panic!("{e}"));
        let world_from_camera = Rigid::new(DQuat::IDENTITY, DVec3::new(x, 0.0, 0.0));
        let (mut data, mut metres) = (Vec::new(), Vec::new());
        for v in 0..48 {
            for u in 0..64 {
                let ray = camera.ray(DVec2::new(f64::from(u), f64::from(v)));
                let on_wall = world_from_camera.transform_point(ray * WALL_Z);
                for c in 0..3 {
                    let texture = 110.0
                        + 60.0 * (3.0 * on_wall.x + f64::from(c)).sin() * (2.0 * on_wall.y).cos();
                    data.push((texture * gain).round().clamp(0.0, 255.0) as u8);
                }
                metres.push(WALL_Z as f32);
            }
        }
        SyncedFrame {
            camera_name: "front".into(),
            stamp_nanos: (secs * 1e9) as i64,
            frame_id: "camera".into(),
            rgb: RgbImage {
                width: 64,
                height: 48,
                data,
            },
            depth: with_depth.then_some(DepthImage {
                width: 64,
                height: 48,
                metres,
            }),
            camera,
            world_from_camera,
        }
    }

    fn mean_level(frame: &SyncedFrame) -> f64 {
        frame.rgb.data.iter().map(|&c| f64::from(c)).sum::<f64>() / frame.rgb.data.len() as f64
    }

    #[test]
    fn a_keyframe_brightened_by_the_exposure_is_brought_back_to_its_neighbours_colour() {
        let mut tracker = ExposureTracker::default();
        let mut first = frame(0.0, 1.0, 0.0, true);
        assert_eq!(tracker.compensate(&mut first, None).gain, 1.0);
        let mut second = frame(0.15, 1.15, 0.3, true);
        let untouched = frame(0.15, 1.0, 0.3, true);
        let done = tracker.compensate(&mut second, Some(&first));
        assert!(done.shared_pixels >= MIN_SHARED_PIXELS, "{done:?}");
        // The running reference moved a little towards the brighter frame (0.3 s of 20 s).
        assert!((done.gain - 1.15).abs() < 0.02, "{done:?}");
        let worst = second
            .rgb
            .data
            .iter()
            .zip(&untouched.rgb.data)
            .map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs())
            .max();
        assert!(worst <= Some(4), "{worst:?}");
    }

    #[test]
    fn a_steady_exposure_leaves_every_keyframe_byte_for_byte() {
        let mut tracker = ExposureTracker::default();
        let mut previous: Option<SyncedFrame> = None;
        for k in 0..8 {
            let mut next = frame(0.1 * f64::from(k), 1.0, 0.5 * f64::from(k), true);
            let original = next.clone();
            let done = tracker.compensate(&mut next, previous.as_ref());
            assert_eq!(done.gain, 1.0, "keyframe {k}");
            assert_eq!(next, original);
            previous = Some(next);
        }
    }

    #[test]
    fn a_hunting_exposure_is_flattened_around_its_running_mean() {
        // ±15% over a 4 s period, as the sim's realistic preset hunts.
        let hunt = |secs: f64| 1.0 + 0.15 * (secs / 4.0 * std::f64::consts::TAU).sin();
        let mut tracker = ExposureTracker::default();
        let mut previous: Option<SyncedFrame> = None;
        let (mut before, mut after) = (Vec::new(), Vec::new());
        for k in 0..40 {
            let secs = 0.3 * f64::from(k);
            // Back and forth along the wall so every step shares most of its view.
            let x = 0.1 * (f64::from(k) * 0.7).sin();
            let mut next = frame(x, hunt(secs), secs, true);
            let reference = mean_level(&frame(x, 1.0, secs, true));
            before.push(mean_level(&next) / reference);
            tracker.compensate(&mut next, previous.as_ref());
            after.push(mean_level(&next) / reference);
            previous = Some(next);
        }
        let spread = |v: &[f64]| {
            v.iter().copied().fold(f64::MIN, f64::max) / v.iter().copied().fold(f64::MAX, f64::min)
        };
        assert!(spread(&before) > 1.3, "{}", spread(&before));
        assert!(spread(&after) < 1.04, "{}", spread(&after));
        assert!(after.iter().all(|r| r.is_finite()));
    }

    #[test]
    fn without_depth_or_shared_surface_the_exposure_is_taken_as_unchanged() {
        let mut tracker = ExposureTracker::default();
        let mut first = frame(0.0, 1.0, 0.0, false);
        tracker.compensate(&mut first, None);
        let mut blind = frame(0.1, 1.2, 0.3, false);
        let original = blind.clone();
        let done = tracker.compensate(&mut blind, Some(&first));
        assert_eq!((done.gain, done.shared_pixels), (1.0, 0));
        assert_eq!(blind, original);
        // Every pixel clipped: nothing to measure a ratio on.
        let mut white = frame(0.0, 1.0, 0.6, true);
        white.rgb.data.fill(255);
        let mut next = frame(0.05, 1.2, 0.9, true);
        next.rgb.data.fill(255);
        let mut tracker = ExposureTracker::default();
        tracker.compensate(&mut white, None);
        assert_eq!(tracker.compensate(&mut next, Some(&white)).shared_pixels, 0);
        // Empty images and a camera far away (no overlap) do not panic either.
        let mut empty = frame(0.0, 1.0, 1.2, true);
        empty.rgb = RgbImage {
            width: 0,
            height: 0,
            data: Vec::new(),
        };
        empty.depth = Some(DepthImage {
            width: 0,
            height: 0,
            metres: Vec::new(),
        });
        assert_eq!(tracker.compensate(&mut empty, Some(&next)).gain, 1.0);
        let mut far = frame(100.0, 1.3, 1.5, true);
        assert_eq!(tracker.compensate(&mut far, Some(&next)).shared_pixels, 0);
    }

    #[test]
    fn keyframes_go_to_windows_and_features_with_their_colour_compensated_or_as_sent_when_off() {
        use crate::window::{Keyframes, WindowSection};
        for on in [true, false] {
            let mut store = Keyframes::new(WindowSection {
                views: 2,
                exposure_compensation: on,
                ..WindowSection::default()
            });
            assert!(store.offer(&frame(0.0, 1.0, 0.0, true)));
            let bright = frame(0.25, 1.15, 0.3, true);
            assert!(store.offer(&bright), "moved 0.25 m");
            let newest = store
                .newest()
                .cloned()
                .unwrap_or_else(|| panic!("a keyframe"));
            let window = store.take_window().unwrap_or_else(|| panic!("a window"));
            assert_eq!(
                window.last(),
                Some(&newest),
                "the window takes the keyframe as kept"
            );
            let ratio = mean_level(&newest) / mean_level(&frame(0.25, 1.0, 0.3, true));
            if on {
                assert!((ratio - 1.0).abs() < 0.01, "{ratio}");
            } else {
                assert_eq!(newest, bright);
            }
        }
    }
}
