//! Depth validity (REP 117: invalid depth is NaN): every real depth camera returns pixels without
//! a measurement (0 or NaN on dark, shiny or distant surfaces), beyond its range, or isolated at
//! discontinuities. Ingest marks all of them NaN, so later stages never lift, group or pool them,
//! and counts them by cause.

use super::config::IngestSection;
use super::reject::{reject, Reject, Rejection};
use crate::frame::DepthImage;

/// Why depth pixels of one image are invalid.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DepthValidity {
    pub pixels: u64,
    /// NaN, ±∞ or 0 as the camera sent them.
    pub missing: u64,
    /// Outside the configured range.
    pub out_of_range: u64,
    /// No 4-neighbour agrees within the configured ratio.
    pub isolated: u64,
}

impl DepthValidity {
    pub fn invalid(&self) -> u64 {
        self.missing + self.out_of_range + self.isolated
    }

    pub fn add(&mut self, other: &DepthValidity) {
        self.pixels += other.pixels;
        self.missing += other.missing;
        self.out_of_range += other.out_of_range;
        self.isolated += other.isolated;
    }
}

/// Mark every invalid pixel of `depth` NaN and count the causes. A depth image with no valid pixel
/// left is rejected: a window cannot be built on it.
pub fn mark_invalid_depth(
    depth: &mut DepthImage,
    settings: &IngestSection,
) -> Result<DepthValidity, Rejection> {
    let [near, far] = settings.depth_range_m;
    let mut counts = DepthValidity {
        pixels: depth.metres.len() as u64,
        ..DepthValidity::default()
    };
    for z in &mut depth.metres {
        if !(z.is_finite() && *z > 0.0) {
            *z = f32::NAN;
            counts.missing += 1;
        } else if *z < near || *z > far {
            *z = f32::NAN;
            counts.out_of_range += 1;
        }
    }
    if settings.isolated_depth_ratio > 0.0 {
        let isolated = isolated_pixels(
            &depth.metres,
            depth.width as usize,
            depth.height as usize,
            settings.isolated_depth_ratio,
        );
        for i in isolated {
            depth.metres[i] = f32::NAN;
            counts.isolated += 1;
        }
    }
    if counts.pixels > 0 && counts.invalid() == counts.pixels {
        return reject(
            Reject::NoValidDepth,
            format!(
                "depth image {}x{} has no valid pixel ({} missing, {} outside {near}..{far} m, {} isolated)",
                depth.width, depth.height, counts.missing, counts.out_of_range, counts.isolated
            ),
        );
    }
    Ok(counts)
}

/// Valid pixels none of whose valid 4-neighbours is within `ratio` of its depth (a pixel whose
/// neighbours are all invalid is isolated too). Judged on the input, so marking one pixel never
/// makes its neighbour isolated.
fn isolated_pixels(metres: &[f32], width: usize, height: usize, ratio: f32) -> Vec<usize> {
    let mut out = Vec::new();
    if width * height != metres.len() || metres.len() < 2 {
        return out;
    }
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            let z = metres[i];
            if !z.is_finite() {
                continue;
            }
            let agrees = |j: usize| (metres[j] - z).abs() <= ratio * z;
            let any = (x > 0 && agrees(i - 1))
                || (x + 1 < width && agrees(i + 1))
                || (y > 0 && agrees(i - width))
                || (y + 1 < height && agrees(i + width));
            if !any {
                out.push(i);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(width: u32, height: u32, metres: Vec<f32>) -> DepthImage {
        DepthImage {
            width,
            height,
            metres,
        }
    }

    #[test]
    fn missing_out_of_range_and_isolated_pixels_become_nan_and_are_counted() {
        let settings = IngestSection::default();
        // Row 0: a plane at 2 m with a NaN, a 0, an ∞; row 1: too near, too far, and one spike.
        let mut depth = image(
            6,
            2,
            vec![
                2.0,
                f32::NAN,
                0.0,
                f32::INFINITY,
                2.0,
                2.0, //
                0.05,
                20.0,
                2.0,
                2.0,
                5.0,
                2.0,
            ],
        );
        let counts = mark_invalid_depth(&mut depth, &settings).unwrap();
        assert_eq!(counts.pixels, 12);
        assert_eq!(counts.missing, 3);
        assert_eq!(counts.out_of_range, 2);
        // The spike at 5 m among 2 m neighbours, and the 2 m pixel at (0, 0) whose only
        // neighbours are NaN or the 0.05 m pixel.
        assert_eq!(counts.isolated, 2);
        let valid: Vec<usize> = (0..12).filter(|&i| depth.metres[i].is_finite()).collect();
        assert_eq!(valid, [4, 5, 8, 9, 11]);
        assert!(depth.metres.iter().all(|z| z.is_nan() || *z == 2.0));
    }

    #[test]
    fn a_depth_image_without_any_valid_pixel_is_rejected_with_its_reason() {
        let settings = IngestSection::default();
        let mut depth = image(3, 2, vec![0.0; 6]);
        let rejection = mark_invalid_depth(&mut depth, &settings).unwrap_err();
        assert_eq!(rejection.reason, Reject::NoValidDepth);
        let mut depth = image(3, 2, vec![f32::NAN, 30.0, 0.0, 0.0, 0.0, 0.0]);
        assert!(mark_invalid_depth(&mut depth, &settings).is_err());
        // An empty image has nothing to mark and nothing to reject here (dimensions are
        // checked by the decoder).
        let mut empty = image(0, 0, Vec::new());
        assert_eq!(mark_invalid_depth(&mut empty, &settings).unwrap().pixels, 0);
    }

    #[test]
    fn a_clean_surface_keeps_every_pixel_and_zero_ratio_switches_the_isolation_check_off() {
        let slanted: Vec<f32> = (0..48).map(|i| 1.0 + 0.01 * i as f32).collect();
        let mut depth = image(8, 6, slanted.clone());
        let counts = mark_invalid_depth(&mut depth, &IngestSection::default()).unwrap();
        assert_eq!(counts.invalid(), 0);
        assert_eq!(depth.metres, slanted);
        let mut spiky = image(3, 1, vec![1.0, 4.0, 1.0]);
        let off = IngestSection {
            isolated_depth_ratio: 0.0,
            ..IngestSection::default()
        };
        assert_eq!(mark_invalid_depth(&mut spiky, &off).unwrap().isolated, 0);
    }
}
