//! A persistent instance, how window instances merge into it, and the fusion parameters.

use glam::Vec3;

use crate::group::semantics::{MeasuredSize, Vocabulary};
use crate::recon::boxes::{OrientedBox, DEFAULT_TRIM};
use crate::recon::gaussians::{voxel_downsample, Gaussians};
use crate::recon::round::fit_object_box;
use crate::recon::surface::{thin_to_surfaces, thinning_radius};

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
    /// The depth camera's range noise (σ, metres) at the ranges the instance was seen from,
    /// weighted by the Gaussians each window gave it; 0 where none was measured (a clean or
    /// unknown camera). Its box is fitted to its points thinned by it ([`crate::recon::surface`]).
    pub range_noise_m: f32,
    pub range_noise_weight: f32,
    /// Points just beyond its ends where a view saw free space (the newest
    /// [`MAX_SEEN_FREE`]): the object ends before them, so a box of an object
    /// seen in part grows only where no camera saw past it ([`super::amodal::grown_to_length`]).
    pub seen_free: Vec<Vec3>,
}

/// Points an instance keeps where views saw free space beyond it ([`Instance::seen_free`]); the
/// newest are kept. A bound on memory (3 KB an instance), not read off any scene.
pub const MAX_SEEN_FREE: usize = 256;
/// Points of [`Instance::seen_free`] in the cell (this size, m) of one already kept add nothing.
const SEEN_FREE_SPACING_M: f32 = 0.02;

/// Range noise below this (metres) is not thinned: a fifth of the map's 5 cm voxels.
pub const MIN_THINNED_NOISE_M: f32 = 0.01;
/// A thinned box deeper than this along both horizontal axes is no face the map completes (the
/// deepest a name's completion looks for is a third of a bed's 1.55 m).
const MAX_FACE_DEPTH_M: f64 = 0.6;

/// The boxes fitted to an instance ([`Instance::fitted`]): to its points, and to the surface
/// they measure where it was seen through range noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fitted {
    pub points: OrientedBox,
    pub surface: Option<OrientedBox>,
}

impl From<OrientedBox> for Fitted {
    /// A box fitted elsewhere (e.g. already published), without a surface box.
    fn from(points: OrientedBox) -> Self {
        Self {
            points,
            surface: None,
        }
    }
}

impl Instance {
    pub fn bounds(&self) -> (Vec3, Vec3) {
        bounds(&self.gaussians)
    }

    pub fn center(&self) -> Vec3 {
        let (lo, hi) = self.bounds();
        (lo + hi) / 2.0
    }

    /// Whether semantic features ever fell on it: a prototype that is not empty or zero.
    pub fn is_named(&self) -> bool {
        self.prototype.iter().any(|&v| v != 0.0)
    }

    /// Its length and height as its points measure them ([`OrientedBox::principal_extent`]).
    pub fn measured_size(&self) -> MeasuredSize {
        let (length_m, height_m) =
            OrientedBox::principal_extent(&self.gaussians.means, DEFAULT_TRIM);
        MeasuredSize { length_m, height_m }
    }

    /// p(name) for every phrase of `vocabulary`, in its order: its prototype's, less the names
    /// whose objects are never as long or as tall as it is, `size` ([`Instance::measured_size`],
    /// measured once by the caller; [`Vocabulary::probabilities_given`]).
    pub fn name_probabilities(&self, vocabulary: &Vocabulary, size: MeasuredSize) -> Vec<f32> {
        vocabulary.probabilities_given(&self.prototype, Some(size))
    }

    /// The box the map publishes for this instance (and the evaluation scores): fitted to its
    /// points, completed to the whole circle when they are the seen side of a round object.
    pub fn oriented_box(&self) -> OrientedBox {
        fit_object_box(&self.gaussians.means, DEFAULT_TRIM)
    }

    /// Its box ([`Instance::oriented_box`]) and, when `with_surface` asks for it and it was seen
    /// through range noise, the box of the surface its points measure ([`crate::recon::surface`]):
    /// only for boxes thin enough along a horizontal axis to be a face once thinned.
    pub fn fitted(&self, with_surface: bool) -> Fitted {
        let points = self.oriented_box();
        let could_be_a_face = points.size.x.min(points.size.y)
            <= MAX_FACE_DEPTH_M + 4.0 * f64::from(self.range_noise_m);
        let surface = thinning_radius(self.range_noise_m)
            .filter(|_| {
                with_surface && self.range_noise_m >= MIN_THINNED_NOISE_M && could_be_a_face
            })
            .map(|radius| {
                fit_object_box(
                    &thin_to_surfaces(&self.gaussians.means, radius),
                    DEFAULT_TRIM,
                )
            });
        Fitted { points, surface }
    }

    /// Add `weight` of observations made through range noise `sigma_m` to the weighted mean
    /// noise; an unmeasured noise (`None`) adds nothing.
    pub(super) fn observe_noise(&mut self, sigma_m: Option<f32>, weight: f32) {
        let Some(sigma) = sigma_m.filter(|s| s.is_finite() && *s >= 0.0 && weight > 0.0) else {
            return;
        };
        let total = self.range_noise_weight + weight;
        self.range_noise_m += (sigma - self.range_noise_m) * (weight / total);
        self.range_noise_weight = total;
    }

    /// Keep `points` where a view saw free space beyond it ([`Instance::seen_free`]): those not
    /// already kept, the oldest dropped beyond the cap.
    pub(super) fn remember_free(&mut self, points: impl IntoIterator<Item = Vec3>) {
        // By cell of the spacing: a point in a kept point's cell adds nothing.
        let cell = |p: Vec3| (p / SEEN_FREE_SPACING_M).floor().as_ivec3();
        let mut known: rustc_hash::FxHashSet<glam::IVec3> =
            self.seen_free.iter().map(|p| cell(*p)).collect();
        for p in points.into_iter().filter(|p| p.is_finite()) {
            if known.insert(cell(p)) {
                self.seen_free.push(p);
            }
        }
        let excess = self.seen_free.len().saturating_sub(MAX_SEEN_FREE);
        self.seen_free.drain(..excess);
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
        let measured = (other.range_noise_weight > 0.0).then_some(other.range_noise_m);
        self.observe_noise(measured, other.range_noise_weight);
        self.remember_free(other.seen_free.iter().copied());
        self.confidence = self.confidence.max(other.confidence);
        self.observations += other.observations;
        self.first_seen_nanos = self.first_seen_nanos.min(other.first_seen_nanos);
        self.last_seen_nanos = self.last_seen_nanos.max(other.last_seen_nanos);
    }
}

#[cfg(test)]
impl Instance {
    /// A test instance of small opaque Gaussians at `points`, named by `prototype`, seen by
    /// three windows through a clean camera from nowhere in particular.
    pub(crate) fn of_points(id: &str, points: &[Vec3], prototype: &[f32]) -> Self {
        let mut gaussians = Gaussians::with_dims(0, 0);
        for p in points {
            let (scale, rotation) = (Vec3::splat(0.01), glam::Quat::IDENTITY);
            gaussians.push(*p, 1.0, scale, rotation, Vec3::ONE, &[], &[]);
        }
        Self {
            id: id.into(),
            gaussians,
            prototype: prototype.to_vec(),
            prototype_weight: 1.0,
            confidence: 1.0,
            observations: 3,
            first_seen_nanos: 0,
            last_seen_nanos: 0,
            viewpoint: None,
            viewpoint_weight: 0.0,
            range_noise_m: 0.0,
            range_noise_weight: 0.0,
            seen_free: Vec::new(),
        }
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
