//! What association and the fold rules measure of an instance's points: a footprint (a
//! subsample, its bounds and point spacing) for overlap queries on a hash grid, and the per-pass
//! cache of footprints, bounds and boxes the fold rules share.

use glam::Vec3;
use rustc_hash::FxHashMap;

use crate::graph::instance::{bounds, Instance};
use crate::recon::boxes::{trimmed_range, OrientedBox};
use crate::recon::gaussians::Gaussians;

/// The points of an instance as association sees them: a subsample, its bounds, its typical
/// point spacing, and a hash grid for radius queries.
pub(super) struct Footprint {
    points: Vec<Vec3>,
    lo: Vec3,
    hi: Vec3,
    pub(super) spacing: f32,
    /// The hash grid of `points` the last query built, with its radius: association asks about
    /// one instance (the room's, most of all) from many window instances at the same radius,
    /// and rebuilding the grid per query was a tenth of a window's fusion (a perf profile of
    /// benchmark 13200-13219; the queries themselves another tenth).
    grid: std::cell::RefCell<Option<PointGrid>>,
}

/// At most this many points per instance enter the overlap test (an even stride).
const ASSOCIATION_POINTS: usize = 2048;

impl Footprint {
    pub(super) fn new(g: &Gaussians, min_spacing: f32) -> Self {
        let stride = g.len().div_ceil(ASSOCIATION_POINTS).max(1);
        let points: Vec<Vec3> = g.means.iter().step_by(stride).copied().collect();
        let (lo, hi) = bounds(g);
        // Median nearest-neighbour distance over a few probes: far objects seen at a fixed pixel
        // pitch are sparse, and the overlap radius must follow.
        let probes = points.len().div_ceil(64).max(1);
        let mut nearest: Vec<f32> = points
            .iter()
            .step_by(probes)
            .enumerate()
            .map(|(k, a)| {
                points
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| *j != k * probes)
                    .map(|(_, b)| a.distance_squared(*b))
                    .fold(f32::INFINITY, f32::min)
                    .sqrt()
            })
            .filter(|d| d.is_finite())
            .collect();
        nearest.sort_by(f32::total_cmp);
        let spacing = nearest.get(nearest.len() / 2).copied().unwrap_or(0.0);
        Self {
            points,
            lo,
            hi,
            spacing: spacing.max(min_spacing),
            grid: Default::default(),
        }
    }

    /// Fraction of the smaller footprint's points that have a point of the other within
    /// `radius`: 1 for a view of part of the same surface, ~0 for a neighbouring object.
    pub(super) fn overlap(&self, other: &Footprint, radius: f32) -> f32 {
        if self.points.len() <= other.points.len() {
            self.covered_by(other, radius)
        } else {
            other.covered_by(self, radius)
        }
    }

    /// Fraction of this footprint's points that have a point of `other` within `radius`.
    pub(super) fn covered_by(&self, other: &Footprint, radius: f32) -> f32 {
        if self.apart(other.lo, other.hi, radius) {
            return 0.0;
        }
        let mut cached = other.grid.borrow_mut();
        let grid = match cached.take() {
            Some(grid) if grid.radius.to_bits() == radius.to_bits() => grid,
            _ => PointGrid::new(&other.points, radius),
        };
        let hits = self
            .points
            .iter()
            .filter(|p| grid.has_within(**p, &other.points))
            .count();
        *cached = Some(grid);
        hits as f32 / self.points.len().max(1) as f32
    }

    /// Whether the box `lo`..`hi` lies farther than `margin` from this footprint's bounds.
    pub(super) fn apart(&self, lo: Vec3, hi: Vec3, margin: f32) -> bool {
        (0..3).any(|a| self.lo[a] - margin > hi[a] || lo[a] - margin > self.hi[a])
    }
}

/// Instances' point footprints, built on first use, and bounds that hold each instance's points
/// (an instance that absorbed another holds the union of both bounds).
pub(super) struct Footprints {
    pub(super) voxel: f32,
    pub(super) built: Vec<Option<Footprint>>,
    pub(super) bounds: Vec<(Vec3, Vec3)>,
    /// [`Footprints::back_bounds`] of instances seen through range noise, on first use.
    pub(super) spread: Vec<Option<(Vec3, Vec3)>>,
    /// Boxes as the instances were at the start of the pass ([`Footprints::oriented_box`]).
    pub(super) boxes: Vec<Option<OrientedBox>>,
}

/// Share of an instance's points left out on each side of each axis by the bounds
/// [`Footprints::back_bounds`] judges a noisy back by, and the width of a normal distribution's
/// interval between those shares, in σ: 5% each side, ±1.645 σ.
pub(super) const BACK_SPREAD_SHARE: f32 = 0.05;
const BACK_SPREAD_SIGMAS: f32 = 3.29;

impl Footprints {
    /// Instance `k`'s box as it was at the start of the pass, fitted on first use: only pairs
    /// near enough to matter ask (at 500 instances, fitting every box was most of a window's
    /// fusion). A pair that folds asks for both boxes first, so a survivor keeps the box it had
    /// until the next pass.
    pub(super) fn oriented_box(&mut self, instances: &[Instance], k: usize) -> OrientedBox {
        *self.boxes[k].get_or_insert_with(|| instances[k].oriented_box())
    }

    /// The bounds [`is_back_of`] judges instance `k` as a back by, with the spread range noise
    /// adds to them along the view: its bounds for a clean camera; seen through range noise
    /// (σ measured), the bounds of its points' 5th to 95th percentiles per axis (a few points
    /// drawn 3 σ out by the noise would set the bounds) and that interval's width of a normal
    /// distribution of σ.
    pub(super) fn back_bounds(&mut self, instances: &[Instance], k: usize) -> ((Vec3, Vec3), f32) {
        let sigma = instances[k].range_noise_m;
        if !(sigma.is_finite() && sigma > 0.0) {
            return (self.bounds[k], 0.0);
        }
        let spread = *self.spread[k]
            .get_or_insert_with(|| share_bounds(&instances[k].gaussians.means, BACK_SPREAD_SHARE));
        (spread, BACK_SPREAD_SIGMAS * sigma)
    }

    /// Whether instances `a` and `b` lie so far apart that neither their footprints overlap nor
    /// boxes fitted to their points (as they were when `bounds` were taken) intersect. A box
    /// fitted at any yaw to points within bounds of diagonal d lies within 1.75 d of the bounds'
    /// centre, and a union's centre within half its diagonal of a part's (2.25 d). A footprint's
    /// spacing is at most its bounds' diagonal (or the voxel), so footprints farther apart than
    /// 1.5 × that (per axis, √3 × that in distance) overlap 0.
    pub(super) fn far_apart(&self, a: usize, b: usize) -> bool {
        let ((lo_a, hi_a), (lo_b, hi_b)) = (self.bounds[a], self.bounds[b]);
        let (d_a, d_b) = ((hi_a - lo_a).length(), (hi_b - lo_b).length());
        let boxes = 2.25 * (d_a + d_b);
        let footprints = 0.5 * (d_a + d_b) + 2.6 * d_a.max(d_b).max(self.voxel);
        let distance = ((lo_a + hi_a) / 2.0).distance((lo_b + hi_b) / 2.0);
        distance > 1.01 * boxes.max(footprints) + 1e-3
    }

    /// The share of the smaller of instances `a` and `b` lying on the other (see
    /// [`Footprint::overlap`]), their footprints built if they are not yet.
    pub(super) fn overlap(&mut self, instances: &[Instance], a: usize, b: usize) -> f32 {
        for k in [a, b] {
            if self.built[k].is_none() {
                self.built[k] = Some(Footprint::new(&instances[k].gaussians, self.voxel));
            }
        }
        match (&self.built[a], &self.built[b]) {
            (Some(fa), Some(fb)) => fa.overlap(fb, 1.5 * fa.spacing.max(fb.spacing)),
            _ => 0.0,
        }
    }
}

/// Per axis, the bounds of the finite `points` leaving `share` of them out at each end (the
/// box fit's [`trimmed_range`]); empty bounds (+∞, −∞) without finite points.
pub(super) fn share_bounds(points: &[Vec3], share: f32) -> (Vec3, Vec3) {
    let finite: Vec<Vec3> = points.iter().copied().filter(|p| p.is_finite()).collect();
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    if finite.is_empty() {
        return (lo, hi);
    }
    for axis in 0..3 {
        let mut values: Vec<f64> = finite.iter().map(|p| f64::from(p[axis])).collect();
        let (low, high) = trimmed_range(&mut values, f64::from(share));
        lo[axis] = low as f32;
        hi[axis] = high as f32;
    }
    (lo, hi)
}

/// Points hashed into cells of one radius, for "nearest point within the radius" queries: the
/// points' indices sorted by cell, each occupied cell its range of them (no allocation per cell).
struct PointGrid {
    radius: f32,
    order: Vec<u32>,
    cells: FxHashMap<(i32, i32, i32), (u32, u32)>,
}

impl PointGrid {
    fn new(points: &[Vec3], radius: f32) -> Self {
        let mut keyed: Vec<((i32, i32, i32), u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (Self::cell(*p, radius), i as u32))
            .collect();
        keyed.sort_unstable();
        let mut cells: FxHashMap<(i32, i32, i32), (u32, u32)> = FxHashMap::default();
        for (at, (key, _)) in keyed.iter().enumerate() {
            let range = cells.entry(*key).or_insert((at as u32, at as u32));
            range.1 = at as u32 + 1;
        }
        Self {
            radius,
            order: keyed.into_iter().map(|(_, i)| i).collect(),
            cells,
        }
    }

    fn cell(p: Vec3, radius: f32) -> (i32, i32, i32) {
        (
            (p.x / radius).floor() as i32,
            (p.y / radius).floor() as i32,
            (p.z / radius).floor() as i32,
        )
    }

    /// Whether some of `points` (those the grid was built on) lies within the radius of `p` (the
    /// first one found ends the search).
    fn has_within(&self, p: Vec3, points: &[Vec3]) -> bool {
        let (x, y, z) = Self::cell(p, self.radius);
        let r2 = self.radius * self.radius;
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    self.cells
                        .get(&(x + dx, y + dy, z + dz))
                        .is_some_and(|&(start, end)| {
                            self.order[start as usize..end as usize]
                                .iter()
                                .any(|&q| points[q as usize].distance_squared(p) <= r2)
                        })
                })
            })
        })
    }
}
