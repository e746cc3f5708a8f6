//! Reconstruction core (ARCHITECTURE.md §2, §6): cameras and frames, pixel-aligned 3D Gaussians, a
//! tile rasterizer for any channel set, gauge alignment between model passes, and the metrics every
//! benchmark reports.
//!
//! Conventions: transforms are named by what they map (`world_from_camera` takes camera-frame points
//! to the world); camera frames are REP-103 optical frames (z forward, x right, y down), which is
//! also OpenCV's convention; pixel `(u, v)` has its centre at integer coordinates (OpenCV).

pub mod boxes;
pub mod camera;
pub mod depth_noise;
pub mod gauge;
pub mod gaussians;
pub mod metrics;
pub mod raster;
pub mod round;
pub mod surface;

use glam::{DMat3, DQuat, DVec3};

/// The median of `values` (the upper one of an even count: the element a sort would put at
/// `len / 2`), found by selection, which reorders `values`; `None` when empty.
pub fn median(values: &mut [f32]) -> Option<f32> {
    let middle = values.len() / 2;
    (middle < values.len()).then(|| *values.select_nth_unstable_by(middle, f32::total_cmp).1)
}

/// A rigid transform (rotation then translation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    pub rotation: DQuat,
    pub translation: DVec3,
}

impl Default for Rigid {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Rigid {
    pub const IDENTITY: Self = Self {
        rotation: DQuat::IDENTITY,
        translation: DVec3::ZERO,
    };

    pub fn new(rotation: DQuat, translation: DVec3) -> Self {
        Self {
            rotation,
            translation,
        }
    }

    /// `self * other`: apply `other` first.
    pub fn compose(&self, other: &Self) -> Self {
        Self {
            rotation: (self.rotation * other.rotation).normalize(),
            translation: self.translation + self.rotation * other.translation,
        }
    }

    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.inverse();
        Self {
            rotation,
            translation: -(rotation * self.translation),
        }
    }

    pub fn transform_point(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation
    }

    pub fn rotation_matrix(&self) -> DMat3 {
        DMat3::from_quat(self.rotation)
    }

    /// Interpolate: translation linearly, rotation by slerp.
    pub fn lerp(&self, other: &Self, s: f64) -> Self {
        Self {
            rotation: self.rotation.slerp(other.rotation, s).normalize(),
            translation: self.translation.lerp(other.translation, s),
        }
    }

    pub fn is_finite(&self) -> bool {
        self.rotation.is_finite() && self.translation.is_finite()
    }
}

#[cfg(test)]
mod tests {
    use super::median;

    #[test]
    fn the_median_is_the_middle_rank_of_a_sort_and_none_when_empty() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        // Even counts take the upper of the two middle values, as `sorted[len / 2]` does.
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(3.0));
        assert_eq!(median(&mut [7.5]), Some(7.5));
        assert_eq!(median(&mut []), None);
    }
}
