//! A persistent instance, how window instances merge into it, and the fusion parameters.

use glam::Vec3;

use crate::recon::boxes::{OrientedBox, DEFAULT_TRIM};
use crate::recon::gaussians::{voxel_downsample, Gaussians};
use crate::recon::round::fit_object_box;

/// A persistent instance.
#[derive(Debug, Clone, PartialEq)]
pub struct Instance {
    /// Persistent, never reused: `inst_000001`, ...
    pub id: String,
    pub gaussians: Gaussians,
    pub prototype: Vec<f32>,
    pub prototype_weight: f64,
    pub confidence: f32,
    pub observations: u32,
    pub first_seen_nanos: i64,
    pub last_seen_nanos: i64,
    /// Where the cameras that saw it stood: the mean camera centre of the windows it was seen in,
    /// weighted by the Gaussians each gave it (`None` before any, e.g. restored from a map saved
    /// without it). A box seen from one side is completed away from it ([`super::amodal`]).
    pub viewpoint: Option<Vec3>,
    pub viewpoint_weight: f32,
}

impl Instance {
    pub fn bounds(&self) -> (Vec3, Vec3) {
        bounds(&self.gaussians)
    }

    pub fn center(&self) -> Vec3 {
        let (lo, hi) = self.bounds();
        (lo + hi) / 2.0
    }

    /// The box the map publishes for this instance (and the evaluation scores): fitted to its
    /// points, completed to the whole circle when they are the seen side of a round object.
    pub fn oriented_box(&self) -> OrientedBox {
        fit_object_box(&self.gaussians.means, DEFAULT_TRIM)
    }

    /// Add `weight` of observations made from `viewpoint` to the weighted mean viewpoint.
    pub(super) fn observe_from(&mut self, viewpoint: Option<Vec3>, weight: f32) {
        let Some(v) = viewpoint.filter(|v| v.is_finite() && weight > 0.0) else {
            return;
        };
        let total = self.viewpoint_weight + weight;
        self.viewpoint = Some(match self.viewpoint {
            Some(mean) => mean + (v - mean) * (weight / total),
            None => v,
        });
        self.viewpoint_weight = total;
    }

    /// Add Gaussians (voxel-merged, capped) and a prototype observed with `weight` (count-weighted
    /// mean).
    pub(super) fn merge(
        &mut self,
        gaussians: &Gaussians,
        prototype: &[f32],
        weight: f64,
        p: FusionParams,
    ) {
        let mut all = self.gaussians.clone();
        all.extend(gaussians);
        self.gaussians = capped(all, p.voxel, p.max_gaussians_per_instance);
        if self.prototype.is_empty() {
            // First semantics for an instance born without them (e.g. restored from an older map).
            self.prototype = prototype.to_vec();
            self.prototype_weight = if prototype.is_empty() { 0.0 } else { weight };
            return;
        }
        if prototype.is_empty() {
            return;
        }
        let wa = self.prototype_weight;
        for (a, b) in self.prototype.iter_mut().zip(prototype) {
            *a = ((f64::from(*a) * wa + f64::from(*b) * weight) / (wa + weight).max(1e-12)) as f32;
        }
        self.prototype_weight = wa + weight;
    }

    /// Fold `other` (a duplicate of this object) into this instance.
    pub(super) fn absorb(&mut self, other: &Instance, p: FusionParams) {
        self.merge(
            &other.gaussians,
            &other.prototype,
            other.prototype_weight,
            p,
        );
        self.observe_from(other.viewpoint, other.viewpoint_weight);
        self.confidence = self.confidence.max(other.confidence);
        self.observations += other.observations;
        self.first_seen_nanos = self.first_seen_nanos.min(other.first_seen_nanos);
        self.last_seen_nanos = self.last_seen_nanos.max(other.last_seen_nanos);
    }
}

pub(super) fn bounds(g: &Gaussians) -> (Vec3, Vec3) {
    g.means.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), m| (lo.min(*m), hi.max(*m)),
    )
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusionParams {
    /// Voxel size for merging Gaussians and for the overlap test (metres).
    pub voxel: f32,
    /// Minimum overlap for a match: the fraction of the smaller instance's points that have a
    /// point of the other within 1.5 × the coarser point spacing (at least `voxel`).
    pub min_overlap: f32,
    /// Minimum prototype cosine similarity for a match.
    pub min_similarity: f32,
    /// Weight of geometry against semantics in the association score.
    pub geometry_weight: f32,
    pub max_gaussians_per_instance: usize,
    pub max_keyframes: usize,
    /// Instances farther than this from the newest keyframe's camera are dropped (metres).
    pub clearing_radius: f32,
    /// Confidence of a new instance, gained per match, and lost per window that sees free space
    /// where it was and matches it to nothing.
    pub birth_confidence: f32,
    pub confirm_gain: f32,
    pub miss_penalty: f32,
    /// Fraction of an instance's Gaussians a view must see through (in the image, the observed
    /// depth behind them by more than `depth_tolerance`) for the window to count as evidence
    /// that it is gone. A view that sees its surface in place is no such evidence.
    pub visible_fraction: f32,
    /// Depth tolerance of the occlusion test (metres).
    pub depth_tolerance: f32,
    /// Map-level duplicate merging: two instances whose prototypes are at least this similar
    /// and whose boxes overlap by at least `duplicate_iou` (3D IoU), or half of whose smaller
    /// one's points lie on the other's, are one object.
    pub duplicate_similarity: f32,
    pub duplicate_iou: f64,
}

impl Default for FusionParams {
    fn default() -> Self {
        Self {
            voxel: 0.05,
            min_overlap: 0.2,
            min_similarity: 0.5,
            geometry_weight: 0.6,
            max_gaussians_per_instance: 20_000,
            max_keyframes: 64,
            clearing_radius: 30.0,
            birth_confidence: 0.5,
            confirm_gain: 0.2,
            miss_penalty: 0.25,
            visible_fraction: 0.5,
            depth_tolerance: 0.1,
            duplicate_similarity: 0.85,
            duplicate_iou: 0.25,
        }
    }
}

/// Cosine similarity; 0 when either vector is zero.
pub fn cosine(a: &[f32], b: &[f32]) -> f32 {
    let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let na: f32 = a.iter().map(|x| x * x).sum::<f32>().sqrt();
    let nb: f32 = b.iter().map(|x| x * x).sum::<f32>().sqrt();
    if na < 1e-12 || nb < 1e-12 {
        0.0
    } else {
        (dot / (na * nb)).clamp(-1.0, 1.0)
    }
}

/// Keep at most `cap` Gaussians: voxel-downsampled, then an even stride if still too many.
pub(super) fn capped(g: Gaussians, voxel: f32, cap: usize) -> Gaussians {
    let merged = voxel_downsample(&g, voxel).unwrap_or(g);
    if merged.len() <= cap || cap == 0 {
        return merged;
    }
    let stride = merged.len().div_ceil(cap);
    merged.select((0..merged.len()).step_by(stride))
}
