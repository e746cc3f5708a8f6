//! Fusion: associate a window's instances with the persistent ones (3D overlap plus prototype
//! similarity, Kuhn–Munkres, then parts), merge or give birth, fold duplicates named alike, and
//! let instances where a view sees free space lose confidence and die.

use std::collections::VecDeque;

use glam::Vec3;
use pathfinding::prelude::{kuhn_munkres, Matrix};
use rustc_hash::FxHashMap;

use super::error::GraphError;
use super::instance::{bounds, capped, cosine, FusionParams, Instance};
use crate::frame::{Keyframe, WindowInstance, WindowView};
use crate::recon::boxes::{trimmed_range, OrientedBox, DEFAULT_TRIM};
use crate::recon::depth_noise::median_measured;
use crate::recon::gaussians::Gaussians;
use crate::recon::round::fit_object_box;

/// What fusion asks of the vocabulary about instances' prototypes. Any `Fn(&[f32], &[f32]) ->
/// bool` is one that answers only the first question.
pub trait Kinds {
    /// Whether two prototypes name one kind of object (not structure).
    fn same_kind(&self, a: &[f32], b: &[f32]) -> bool;
    /// The longest horizontal side (m) an object of `prototype`'s kind has; `None` when unknown.
    fn largest_side(&self, _prototype: &[f32]) -> Option<f64> {
        None
    }
}

impl<F: Fn(&[f32], &[f32]) -> bool> Kinds for F {
    fn same_kind(&self, a: &[f32], b: &[f32]) -> bool {
        self(a, b)
    }
}

/// What one fusion step did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FusionReport {
    /// For each window instance, the persistent id it became part of.
    pub assigned: Vec<String>,
    pub merged: usize,
    pub born: usize,
    /// Duplicates folded into an older instance: (absorbed id, surviving id).
    pub absorbed: Vec<(String, String)>,
    pub missed: usize,
    pub died: usize,
    pub cleared: usize,
}

impl FusionReport {
    /// Record folds (absorbed, survivor): window instances that went into an absorbed instance
    /// are reported under its survivor. Returns the survivors' ids.
    fn record_folds(&mut self, folded: Vec<(String, String)>) -> rustc_hash::FxHashSet<String> {
        let mut survivors = rustc_hash::FxHashSet::default();
        for (absorbed, survivor) in folded {
            for id in self.assigned.iter_mut().filter(|id| **id == absorbed) {
                id.clone_from(&survivor);
            }
            survivors.insert(survivor.clone());
            self.absorbed.push((absorbed, survivor));
        }
        survivors
    }
}

/// The persistent map.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SceneMap {
    pub instances: Vec<Instance>,
    pub keyframes: VecDeque<Keyframe>,
    pub next_id: u64,
    pub params: FusionParams,
}

/// The points of an instance as association sees them: a subsample, its bounds, its typical
/// point spacing, and a hash grid for radius queries.
struct Footprint {
    points: Vec<Vec3>,
    lo: Vec3,
    hi: Vec3,
    spacing: f32,
}

/// The key that sorts instances oldest first: when first seen, then the order of birth (ids are
/// numbered as instances are born, so a longer id is younger). Instances born in one window tie
/// on the first: the lower id is the one the map listed first, so a user holding it keeps it
/// (ranking by observations instead let a piece seen twice take over the object the user had
/// been shown under the other id).
fn birth_order(instance: &Instance) -> (i64, usize, &str) {
    (
        instance.first_seen_nanos,
        instance.id.len(),
        instance.id.as_str(),
    )
}

/// Whether `prototype` names an object, not structure: `same_kind` of it with itself.
fn names_an_object(same_kind: &dyn Fn(&[f32], &[f32]) -> bool, prototype: &[f32]) -> bool {
    !prototype.is_empty() && same_kind(prototype, prototype)
}

/// Two objects whose boxes overlap at least this much (3D IoU) are one, whatever their names
/// and prototypes: solid things do not pass through each other, and in the 200 training rooms no
/// two objects' true boxes overlap by more than 0.04 (a pillow on a bed). The map's boxes are
/// noisier than true ones, hence the margin; what overlaps this much is one object the
/// vocabulary named two ways (a trash bin listed twice, once as a desk).
const ONE_SPACE_IOU: f64 = 0.4;

/// A window instance left over by the one-to-one matching is a part of a persistent instance
/// when at least this share of its points lies on it.
const PART_COVERED: f32 = 0.5;

/// Two instances touch when at least this share of the smaller one's points has a point of the
/// other within the overlap radius (a seam, not an overlap).
const FRAGMENT_TOUCH: f32 = 0.02;

/// Fragments fold only when the box of both together is at most this many times as long as
/// the longest object of their name ([`Kinds::largest_side`]; the margin is for depth noise and
/// boxes fitted to a few points): two chairs side by side touch and are named alike, but
/// together they are twice as long as any chair.
const FRAGMENT_SIDE_MARGIN: f64 = 1.5;

/// A leg (or a side panel): an instance at most this thick along x or y (axis-aligned bounds),
/// at least [`LEG_MIN_HEIGHT_M`] tall and twice as tall as it is thick.
const LEG_MAX_THICKNESS_M: f32 = 0.2;
const LEG_MIN_HEIGHT_M: f32 = 0.3;
/// A leg's top lies at most this far below the top of the surface it carries (a table top's
/// thickness, and the top seen a little higher through depth noise) ...
const LEG_TOP_BELOW_M: f32 = 0.15;
/// ... and at most this far above it.
const LEG_TOP_ABOVE_M: f32 = 0.03;
/// A leg lies under the surface: its bounds within the surface's grown by this along x and y
/// (a top seen in part, at a slant, ends short of its legs by up to 0.2 m on the benchmark).
const LEG_INSIDE_M: f32 = 0.15;
/// What a leg carries is at least this wide along x and y.
const SURFACE_MIN_WIDTH_M: f32 = 0.3;

/// Whether an instance with bounds `leg` is a leg (or side panel) of the one with bounds
/// `surface`: thin and upright, under the surface (within its footprint) and ending just below
/// its top, reaching at least as low as the surface does. The window grouping often cuts a table's legs or a desk's side from its top (a leg is
/// a few pixels wide at the model's resolution) and the semantic model then names a lone leg
/// "chair" or "trash bin"; a chair, a bin or a cabinet under a desk is thicker, a floor lamp or
/// a chair's back rises above the top, and a bottle stands on it.
pub fn is_leg_of(leg: (Vec3, Vec3), surface: (Vec3, Vec3)) -> bool {
    let (size, surface_size) = (leg.1 - leg.0, surface.1 - surface.0);
    let thickness = size.x.min(size.y);
    let finite =
        leg.0.is_finite() && leg.1.is_finite() && surface.0.is_finite() && surface.1.is_finite();
    let upright =
        thickness <= LEG_MAX_THICKNESS_M && size.z >= LEG_MIN_HEIGHT_M && size.z >= 2.0 * thickness;
    let carries = surface_size.x.min(surface_size.y) >= SURFACE_MIN_WIDTH_M;
    let under = (0..2).all(|a| {
        leg.0[a] >= surface.0[a] - LEG_INSIDE_M && leg.1[a] <= surface.1[a] + LEG_INSIDE_M
    });
    let top = leg.1.z - surface.1.z;
    // A leg reaches at least as low as what it carries; a monitor on a desk does not.
    let reaches_down = leg.0.z <= surface.0.z + LEG_TOP_ABOVE_M;
    finite
        && upright
        && carries
        && under
        && reaches_down
        && (-LEG_TOP_BELOW_M..=LEG_TOP_ABOVE_M).contains(&top)
}

/// A back (a bed's headboard, a sofa's back): an instance at most this thick along x or y ...
const BACK_MAX_THICKNESS_M: f32 = 0.4;
/// ... lying along a side of the seat it stands behind: at least this share of the shorter of
/// its length and that side beside each other ...
const BACK_ALONG_SHARE: f32 = 0.6;
/// ... within this of that side (a bed's middle under its pillows and duvet goes unseen or to
/// the pillows: the benchmark's beds left up to 0.9 m between foot and headboard) ...
const BACK_GAP_M: f32 = 1.0;
/// ... and rising at least this far above the seat's top.
const BACK_RISES_M: f32 = 0.15;

/// Whether an instance with bounds `back` is the back of the one with bounds `seat`: thin,
/// lying along one side of the seat (mostly beside that side, at most
/// [`BACK_GAP_M`] from it, beyond the seat's middle) and rising above the seat's top. The window
/// grouping cuts a bed's headboard from its mattress when the pillows between them are their
/// own instances. Twin beds do not fold: a headboard lies along its own bed's end, beside the
/// other bed, not along it; a chair behind another has a back as high as its neighbour's.
/// `noise_spread` (m, 0 for a clean camera) is how much thicker than it is the back's bounds
/// are drawn by range noise: a headboard seen from 5 m through a consumer camera's noise (σ 15
/// cm) spreads over more than a metre along the view.
pub fn is_back_of(back: (Vec3, Vec3), seat: (Vec3, Vec3), noise_spread: f32) -> bool {
    let finite = back.0.is_finite()
        && back.1.is_finite()
        && seat.0.is_finite()
        && seat.1.is_finite()
        && noise_spread.is_finite();
    if !finite || noise_spread < 0.0 {
        return false;
    }
    let size = back.1 - back.0;
    // The back's thin axis is its normal; its length runs along the other.
    let (normal, along) = if size.x <= size.y { (0, 1) } else { (1, 0) };
    let length = size[along];
    // The noise may make a back look deeper than it is, never longer than it is deep: a blob
    // no longer than its noisy depth stays no back.
    let thickness = (size[normal] - noise_spread).max(0.0);
    let thin = thickness <= BACK_MAX_THICKNESS_M && length >= 2.0 * size[normal];
    let beside = (back.1[along].min(seat.1[along]) - back.0[along].max(seat.0[along])).max(0.0);
    let side = seat.1[along] - seat.0[along];
    let alongside = length > 0.0 && beside >= BACK_ALONG_SHARE * length.min(side);
    // Beyond one end of the seat along the normal, within the gap (or overlapping that end).
    let middle = (seat.0[normal] + seat.1[normal]) / 2.0;
    let back_middle = (back.0[normal] + back.1[normal]) / 2.0;
    let gap = if back_middle >= middle {
        back.0[normal] - seat.1[normal]
    } else {
        seat.0[normal] - back.1[normal]
    };
    let beyond = (back_middle - middle).abs() >= (seat.1[normal] - seat.0[normal]) / 4.0;
    thin && alongside && beyond && gap <= BACK_GAP_M && back.1.z >= seat.1.z + BACK_RISES_M
}

/// At most this many points per instance enter the overlap test (an even stride).
const ASSOCIATION_POINTS: usize = 2048;

impl Footprint {
    fn new(g: &Gaussians, min_spacing: f32) -> Self {
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
        }
    }

    /// Fraction of the smaller footprint's points that have a point of the other within
    /// `radius`: 1 for a view of part of the same surface, ~0 for a neighbouring object.
    fn overlap(&self, other: &Footprint, radius: f32) -> f32 {
        if self.points.len() <= other.points.len() {
            self.covered_by(other, radius)
        } else {
            other.covered_by(self, radius)
        }
    }

    /// Fraction of this footprint's points that have a point of `other` within `radius`.
    fn covered_by(&self, other: &Footprint, radius: f32) -> f32 {
        if self.apart(other.lo, other.hi, radius) {
            return 0.0;
        }
        let grid = PointGrid::new(&other.points, radius);
        let hits = self.points.iter().filter(|p| grid.has_within(**p)).count();
        hits as f32 / self.points.len().max(1) as f32
    }

    /// Whether the box `lo`..`hi` lies farther than `margin` from this footprint's bounds.
    fn apart(&self, lo: Vec3, hi: Vec3, margin: f32) -> bool {
        (0..3).any(|a| self.lo[a] - margin > hi[a] || lo[a] - margin > self.hi[a])
    }
}

/// Instances' point footprints, built on first use, and bounds that hold each instance's points
/// (an instance that absorbed another holds the union of both bounds).
struct Footprints {
    voxel: f32,
    built: Vec<Option<Footprint>>,
    bounds: Vec<(Vec3, Vec3)>,
    /// [`Footprints::back_bounds`] of instances seen through range noise, on first use.
    spread: Vec<Option<(Vec3, Vec3)>>,
    /// Boxes as the instances were at the start of the pass ([`Footprints::oriented_box`]).
    boxes: Vec<Option<OrientedBox>>,
}

/// Share of an instance's points left out on each side of each axis by the bounds
/// [`Footprints::back_bounds`] judges a noisy back by, and the width of a normal distribution's
/// interval between those shares, in σ: 5% each side, ±1.645 σ.
const BACK_SPREAD_SHARE: f32 = 0.05;
const BACK_SPREAD_SIGMAS: f32 = 3.29;

impl Footprints {
    /// Instance `k`'s box as it was at the start of the pass, fitted on first use: only pairs
    /// near enough to matter ask (at 500 instances, fitting every box was most of a window's
    /// fusion). A pair that folds asks for both boxes first, so a survivor keeps the box it had
    /// until the next pass.
    fn oriented_box(&mut self, instances: &[Instance], k: usize) -> OrientedBox {
        *self.boxes[k].get_or_insert_with(|| instances[k].oriented_box())
    }

    /// The bounds [`is_back_of`] judges instance `k` as a back by, with the spread range noise
    /// adds to them along the view: its bounds for a clean camera; seen through range noise
    /// (σ measured), the bounds of its points' 5th to 95th percentiles per axis (a few points
    /// drawn 3 σ out by the noise would set the bounds) and that interval's width of a normal
    /// distribution of σ.
    fn back_bounds(&mut self, instances: &[Instance], k: usize) -> ((Vec3, Vec3), f32) {
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
    fn far_apart(&self, a: usize, b: usize) -> bool {
        let ((lo_a, hi_a), (lo_b, hi_b)) = (self.bounds[a], self.bounds[b]);
        let (d_a, d_b) = ((hi_a - lo_a).length(), (hi_b - lo_b).length());
        let boxes = 2.25 * (d_a + d_b);
        let footprints = 0.5 * (d_a + d_b) + 2.6 * d_a.max(d_b).max(self.voxel);
        let distance = ((lo_a + hi_a) / 2.0).distance((lo_b + hi_b) / 2.0);
        distance > 1.01 * boxes.max(footprints) + 1e-3
    }

    /// The share of the smaller of instances `a` and `b` lying on the other (see
    /// [`Footprint::overlap`]), their footprints built if they are not yet.
    fn overlap(&mut self, instances: &[Instance], a: usize, b: usize) -> f32 {
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
fn share_bounds(points: &[Vec3], share: f32) -> (Vec3, Vec3) {
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

/// Points hashed into cells of one radius, for "nearest point within the radius" queries.
struct PointGrid<'a> {
    radius: f32,
    cells: FxHashMap<(i32, i32, i32), Vec<&'a Vec3>>,
}

impl<'a> PointGrid<'a> {
    fn new(points: &'a [Vec3], radius: f32) -> Self {
        let mut cells: FxHashMap<(i32, i32, i32), Vec<&Vec3>> = FxHashMap::default();
        for p in points {
            cells.entry(Self::cell(*p, radius)).or_default().push(p);
        }
        Self { radius, cells }
    }

    fn cell(p: Vec3, radius: f32) -> (i32, i32, i32) {
        (
            (p.x / radius).floor() as i32,
            (p.y / radius).floor() as i32,
            (p.z / radius).floor() as i32,
        )
    }

    /// Whether some point lies within the radius of `p` (the first one found ends the search).
    fn has_within(&self, p: Vec3) -> bool {
        let (x, y, z) = Self::cell(p, self.radius);
        let r2 = self.radius * self.radius;
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    self.cells
                        .get(&(x + dx, y + dy, z + dz))
                        .is_some_and(|cell| cell.iter().any(|q| q.distance_squared(p) <= r2))
                })
            })
        })
    }
}

/// The mean camera centre of a window's views (`None` without finite ones).
fn mean_camera_centre(views: &[WindowView]) -> Option<Vec3> {
    let centres: Vec<Vec3> = views
        .iter()
        .map(|v| v.keyframe.world_from_camera.translation.as_vec3())
        .filter(|c| c.is_finite())
        .collect();
    (!centres.is_empty()).then(|| centres.iter().sum::<Vec3>() / centres.len() as f32)
}

/// Sigmas of a depth camera's range noise at the observed depth ([`WindowView`]'s measured
/// noise) that a point and the depth observed through it may differ by before the view counts as
/// seeing free space there: 3 σ of the difference of two noisy depths (√2 σ). Without it, an
/// object 4 m away under 6 mm noise at 1 m (σ 9.6 cm) is "seen through" by a third of its points
/// in every view that does not group it, and dies.
const FREE_SPACE_NOISE_SIGMAS: f32 = 4.2;

/// Fraction of `g`'s Gaussians that `view` sees through: inside the image, in front of the
/// camera, with the observed depth behind them by more than `tolerance`, or the view's depth
/// noise ([`FREE_SPACE_NOISE_SIGMAS`]) if larger (free space where the point was), and the
/// number that project into the image. A point the view does not see
/// (occluded) or sees as a surface proves nothing against the instance; only free space does:
/// a window whose grouping missed an object the camera still sees in place is no evidence that
/// the object is gone.
fn seen_through_fraction(g: &Gaussians, view: &WindowView, tolerance: f32) -> (f32, usize) {
    let noise_at_1m = view.depth_noise_at_1m.unwrap_or(0.0);
    let camera_from_world = view.keyframe.world_from_camera.inverse();
    let camera = &view.keyframe.camera;
    let width = camera.width as usize;
    let (mut through, mut inside) = (0usize, 0usize);
    for m in &g.means {
        let p = camera_from_world.transform_point(m.as_dvec3());
        let Some(pixel) = camera.project(p) else {
            continue;
        };
        let (u, v) = (pixel.x.round(), pixel.y.round());
        if u < 0.0 || v < 0.0 || u >= f64::from(camera.width) || v >= f64::from(camera.height) {
            continue;
        }
        inside += 1;
        let observed = view.depth[v as usize * width + u as usize];
        // Both depths carry the camera's noise where it was measured: free space only beyond
        // what the noise of the two explains.
        let tolerance = tolerance.max(FREE_SPACE_NOISE_SIGMAS * noise_at_1m * observed * observed);
        if observed.is_finite() && observed > 0.0 && (p.z as f32) + tolerance < observed {
            through += 1;
        }
    }
    (through as f32 / g.len().max(1) as f32, inside)
}

impl SceneMap {
    pub fn new(params: FusionParams) -> Self {
        Self {
            params,
            ..Self::default()
        }
    }

    fn new_id(&mut self) -> String {
        self.next_id += 1;
        format!("inst_{:06}", self.next_id)
    }

    /// Fuse one window's instances, seen from `views`, at `stamp_nanos`.
    pub fn fuse(
        &mut self,
        window: Vec<WindowInstance>,
        views: &[WindowView],
        stamp_nanos: i64,
    ) -> Result<FusionReport, GraphError> {
        self.fuse_with(window, views, stamp_nanos, &|_, _| true)
    }

    /// [`SceneMap::fuse`], where map-level duplicates fold only if `same_kind` says so of
    /// their prototypes.
    fn fuse_with(
        &mut self,
        window: Vec<WindowInstance>,
        views: &[WindowView],
        stamp_nanos: i64,
        same_kind: &dyn Fn(&[f32], &[f32]) -> bool,
    ) -> Result<FusionReport, GraphError> {
        let p = self.params;
        let viewpoint = mean_camera_centre(views);
        let noise_at_1m = median_measured(views.iter().map(|v| v.depth_noise_at_1m));
        // The range noise each window instance was measured through: σ₁ · r² at its distance.
        let range_noise: Vec<Option<f32>> = window
            .iter()
            .map(|w| {
                let centroid =
                    w.gaussians.means.iter().sum::<Vec3>() / w.gaussians.len().max(1) as f32;
                let range = viewpoint?.distance(centroid);
                Some(noise_at_1m? * range * range).filter(|s| s.is_finite())
            })
            .collect();
        for (i, w) in window.iter().enumerate() {
            w.gaussians
                .validate()
                .map_err(|e| GraphError::BadInstance(i, e.to_string()))?;
            if w.gaussians.is_empty() {
                return Err(GraphError::BadInstance(i, "no Gaussians".into()));
            }
        }
        let mut report = FusionReport::default();
        let is_object = |prototype: &[f32]| names_an_object(same_kind, prototype);
        // Association scores: geometry (nearest-neighbour overlap within a radius that follows
        // the point spacing) and semantics (prototype cosine), gated.
        let window_footprints: Vec<Footprint> = window
            .iter()
            .map(|w| Footprint::new(&w.gaussians, p.voxel))
            .collect();
        // A persistent instance's footprint is built only when some window instance comes near
        // it: at 500 instances, building them all was most of a window's fusion.
        let map_bounds: Vec<(Vec3, Vec3)> = self
            .instances
            .iter()
            .map(|m| bounds(&m.gaussians))
            .collect();
        let mut map_footprints: Vec<Option<Footprint>> =
            (0..self.instances.len()).map(|_| None).collect();
        // One to one first (Kuhn–Munkres): each persistent instance goes to the window instance
        // that scores best with it, so two window objects never both become one map object.
        let rows = window.len();
        let n = self.instances.len();
        let mut pairs: Vec<Option<usize>> = vec![None; rows];
        let mut gated: Vec<Vec<usize>> = vec![Vec::new(); rows];
        // Columns: every persistent instance, plus one "new instance" column per row so that
        // rows ≤ columns and birth is always possible (score 0).
        let scale = 1_000_000.0f32;
        let mut weights = Matrix::new(rows, n + rows, 0i64);
        for (i, wf) in window_footprints.iter().enumerate() {
            for j in 0..n {
                // A footprint's spacing is at most its bounds' diagonal (or the voxel), so
                // bounds farther apart than 1.5 × that overlap 0 whatever the footprint: the
                // gate below would drop the pair (1% margin against rounding).
                let (lo, hi) = map_bounds[j];
                let reach = 1.515 * wf.spacing.max((hi - lo).length()).max(p.voxel);
                if p.min_overlap > 0.0 && wf.apart(lo, hi, reach) {
                    continue;
                }
                let mf = map_footprints[j]
                    .get_or_insert_with(|| Footprint::new(&self.instances[j].gaussians, p.voxel));
                let radius = 1.5 * wf.spacing.max(mf.spacing);
                let overlap = wf.overlap(mf, radius);
                // Without semantics (no semantic model yet), geometry alone decides.
                let (a, b) = (&window[i].prototype, &self.instances[j].prototype);
                let similarity = (!a.is_empty() && !b.is_empty()).then(|| cosine(a, b));
                if overlap < p.min_overlap || similarity.is_some_and(|s| s < p.min_similarity) {
                    continue;
                }
                // A sighting the vocabulary calls structure does not go into an object: a
                // cabinet's front, seen flat and named a wall once, turned the cabinet into
                // structure, which the object list leaves out.
                if !a.is_empty() && !is_object(a) && is_object(b) {
                    continue;
                }
                let score = match similarity {
                    Some(similarity) => {
                        p.geometry_weight * overlap + (1.0 - p.geometry_weight) * similarity
                    }
                    None => overlap,
                };
                gated[i].push(j);
                weights[(i, j)] = (score * scale).max(1.0) as i64;
            }
        }
        if rows > 0 && n > 0 {
            let (_, assignment) = kuhn_munkres(&weights);
            for (i, &j) in assignment.iter().enumerate() {
                if j < n && weights[(i, j)] > 0 {
                    pairs[i] = Some(j);
                }
            }
        }
        // Then parts: a window instance left over whose points lie mostly on an instance it
        // passes the gate for (a table's leg split from its top by the window's grouping) joins
        // that instance instead of being born under a new id. A window instance that spans a
        // chair and the table beside it lies mostly on neither and is born.
        for i in 0..rows {
            if pairs[i].is_some() {
                continue;
            }
            let wf = &window_footprints[i];
            pairs[i] = gated[i]
                .iter()
                .filter_map(|&j| {
                    // Built: gated pairs passed the geometry gate above.
                    let mf = map_footprints[j].as_ref()?;
                    Some((j, wf.covered_by(mf, 1.5 * wf.spacing.max(mf.spacing))))
                })
                .filter(|&(_, covered)| covered >= PART_COVERED)
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(j, _)| j);
        }
        // Persistent instances that pass the gate for a window instance but are no window
        // instance's best, and look like the one it chose: duplicates of one object (born when
        // an earlier view overlapped too little). A window instance that spans two different
        // objects (a chair the window grouped with its table) folds nothing.
        let chosen: Vec<usize> = pairs.iter().flatten().copied().collect();
        let alike = |a: usize, b: usize| {
            let (pa, pb) = (&self.instances[a].prototype, &self.instances[b].prototype);
            pa.is_empty()
                || pb.is_empty()
                || (cosine(pa, pb) >= p.duplicate_similarity && same_kind(pa, pb))
        };
        let duplicates: Vec<Vec<usize>> = (0..rows)
            .map(|i| match pairs[i] {
                Some(j) => gated[i]
                    .iter()
                    .copied()
                    .filter(|&other| other != j && !chosen.contains(&other) && alike(j, other))
                    .collect(),
                None => Vec::new(),
            })
            .collect();
        let mut matched = vec![false; self.instances.len()];
        let mut absorbed = vec![false; self.instances.len()];
        // Where an absorbed instance went: several window instances may have chosen it.
        let mut survivor: Vec<usize> = (0..self.instances.len()).collect();
        for (i, w) in window.into_iter().enumerate() {
            match pairs[i] {
                Some(j) => {
                    let mut j = j;
                    while survivor[j] != j {
                        j = survivor[j];
                    }
                    matched[j] = true;
                    // Fold duplicates into the oldest of them (ids only ever grow).
                    let mut group: Vec<usize> = std::iter::once(j)
                        .chain(duplicates[i].iter().copied().filter(|&d| !absorbed[d]))
                        .collect();
                    group.sort_by_key(|&k| birth_order(&self.instances[k]));
                    let j = group[0];
                    for &d in &group[1..] {
                        absorbed[d] = true;
                        survivor[d] = j;
                        matched[d] = true;
                        let duplicate = self.instances[d].clone();
                        report
                            .absorbed
                            .push((duplicate.id.clone(), self.instances[j].id.clone()));
                        self.instances[j].absorb(&duplicate, p);
                    }
                    matched[j] = true;
                    let m = &mut self.instances[j];
                    m.observe_from(viewpoint, w.gaussians.len() as f32);
                    m.observe_noise(range_noise[i], w.gaussians.len() as f32);
                    m.merge(&w.gaussians, &w.prototype, w.support.max(1) as f64, p);
                    m.confidence = (m.confidence + p.confirm_gain).min(1.0);
                    m.observations += 1;
                    m.last_seen_nanos = stamp_nanos;
                    report.assigned.push(m.id.clone());
                    report.merged += 1;
                }
                None => {
                    let id = self.new_id();
                    report.assigned.push(id.clone());
                    let seen_by = w.gaussians.len() as f32;
                    let mut born = Instance {
                        id,
                        gaussians: capped(w.gaussians, p.voxel, p.max_gaussians_per_instance),
                        prototype: w.prototype,
                        prototype_weight: w.support.max(1) as f64,
                        confidence: p.birth_confidence,
                        observations: 1,
                        first_seen_nanos: stamp_nanos,
                        last_seen_nanos: stamp_nanos,
                        viewpoint: None,
                        viewpoint_weight: 0.0,
                        range_noise_m: 0.0,
                        range_noise_weight: 0.0,
                    };
                    born.observe_from(viewpoint, seen_by);
                    born.observe_noise(range_noise[i], seen_by);
                    self.instances.push(born);
                    report.born += 1;
                }
            }
        }
        // Unmatched instances where some window view sees free space lose confidence.
        let mut keep: Vec<bool> = (0..self.instances.len())
            .map(|j| j >= absorbed.len() || !absorbed[j])
            .collect();
        for (j, instance) in self.instances.iter_mut().enumerate() {
            if j >= matched.len() || matched[j] {
                continue;
            }
            let expected = views.iter().any(|view| {
                let (fraction, inside) =
                    seen_through_fraction(&instance.gaussians, view, p.depth_tolerance);
                inside > 0 && fraction >= p.visible_fraction
            });
            if expected {
                instance.confidence -= p.miss_penalty;
                report.missed += 1;
                if instance.confidence <= 0.0 {
                    keep[j] = false;
                    report.died += 1;
                }
            }
        }
        // Duplicates the association could not see (two window instances of one object born in
        // the same window, or parts that grew together): fold them, younger into older. Only
        // pairs with an instance this window changed or gave birth to: the others were judged,
        // as they are, by an earlier fusion.
        let touched: Vec<bool> = (0..self.instances.len())
            .map(|j| j >= matched.len() || matched[j])
            .collect();
        let folded = self.fold_duplicates(&mut keep, &touched, same_kind);
        report.record_folds(folded);
        // Clearing radius around the newest camera.
        if let Some(newest) = views.iter().max_by_key(|v| v.keyframe.stamp_nanos) {
            let here = newest.keyframe.world_from_camera.translation.as_vec3();
            for (j, instance) in self.instances.iter().enumerate() {
                if keep[j] && instance.center().distance(here) > p.clearing_radius {
                    keep[j] = false;
                    report.cleared += 1;
                }
            }
        }
        self.retain_marked(&keep);
        for view in views {
            self.keyframes.push_back(view.keyframe.clone());
        }
        while self.keyframes.len() > p.max_keyframes {
            self.keyframes.pop_front();
        }
        Ok(report)
    }

    /// [`SceneMap::fuse`], then [`SceneMap::fold_fragments`] with `kinds`, and both fold rules
    /// again over what each fold grew until neither folds; the report's ids follow the folds (a
    /// window instance assigned to a fragment that folded is reported with the instance it went
    /// into). A map built by fusion has no pair left that either rule would fold.
    pub fn fuse_named(
        &mut self,
        window: Vec<WindowInstance>,
        views: &[WindowView],
        stamp_nanos: i64,
        kinds: impl Kinds,
    ) -> Result<FusionReport, GraphError> {
        let same_kind = |a: &[f32], b: &[f32]| kinds.same_kind(a, b);
        let mut report = self.fuse_with(window, views, stamp_nanos, &same_kind)?;
        // Pairs are judged again only where an instance changed: this window's (any other pair
        // was judged, as it is, by an earlier fusion), then, rule after rule, the survivors of
        // the last folds, until neither rule folds anything.
        let changed: rustc_hash::FxHashSet<String> = report
            .assigned
            .iter()
            .chain(report.absorbed.iter().map(|(_, survivor)| survivor))
            .cloned()
            .collect();
        let mut touched = self.marks(&changed);
        loop {
            let folded = self.fold_fragments_of(&kinds, &touched);
            let survivors = report.record_folds(folded);
            if survivors.is_empty() {
                break;
            }
            let mut keep = vec![true; self.instances.len()];
            let folded = self.fold_duplicates(&mut keep, &self.marks(&survivors), &same_kind);
            self.retain_marked(&keep);
            let survivors = report.record_folds(folded);
            if survivors.is_empty() {
                break;
            }
            touched = self.marks(&survivors);
        }
        Ok(report)
    }

    /// For each instance, whether `ids` holds its id.
    fn marks(&self, ids: &rustc_hash::FxHashSet<String>) -> Vec<bool> {
        self.instances.iter().map(|i| ids.contains(&i.id)).collect()
    }

    /// Drop the instances `keep` does not mark.
    fn retain_marked(&mut self, keep: &[bool]) {
        let mut index = 0;
        self.instances.retain(|_| {
            index += 1;
            keep[index - 1]
        });
    }

    /// Fold fragments of one object into the oldest of them: instances that touch (at least
    /// `FRAGMENT_TOUCH` of the smaller one's points lie next to the other's), have similar
    /// prototypes and are, by `same_kind` (the caller's vocabulary: the same best name, not
    /// structure), the same kind of thing. A bed the window grouping cut into its frame, mattress
    /// and headboard becomes one bed again; two chairs that touch stay two unless their
    /// prototypes and names agree, and a chair against a table never folds into it. A leg under a
    /// surface ([`is_leg_of`]) folds whatever it is named, both being objects (`same_kind` of a
    /// prototype with itself: not structure). Returns (absorbed, survivor) id pairs.
    pub fn fold_fragments(&mut self, kinds: &impl Kinds) -> Vec<(String, String)> {
        let every = vec![true; self.instances.len()];
        self.fold_fragments_of(kinds, &every)
    }

    /// [`SceneMap::fold_fragments`] over the pairs with at least one instance `touched` marks
    /// ([`SceneMap::fold_pairs`]).
    fn fold_fragments_of(&mut self, kinds: &impl Kinds, touched: &[bool]) -> Vec<(String, String)> {
        let p = self.params;
        let same_kind = |a: &[f32], b: &[f32]| kinds.same_kind(a, b);
        let mut keep = vec![true; self.instances.len()];
        let is_object = |prototype: &[f32]| names_an_object(&same_kind, prototype);
        let folded = self.fold_pairs(&mut keep, touched, |instances, footprints, a, b| {
            let (pa, pb) = (&instances[a].prototype, &instances[b].prototype);
            let (bounds_a, bounds_b) = (footprints.bounds[a], footprints.bounds[b]);
            if is_object(pa)
                && is_object(pb)
                && (is_leg_of(bounds_a, bounds_b) || is_leg_of(bounds_b, bounds_a))
            {
                return true;
            }
            if pa.is_empty() || pb.is_empty() || !same_kind(pa, pb) {
                return false;
            }
            let (back_a, spread_a) = footprints.back_bounds(instances, a);
            let (back_b, spread_b) = footprints.back_bounds(instances, b);
            if is_back_of(back_a, bounds_b, spread_a) || is_back_of(back_b, bounds_a, spread_b) {
                return true;
            }
            cosine(pa, pb) >= p.duplicate_similarity
                && footprints.overlap(instances, a, b) >= FRAGMENT_TOUCH
                && kinds.largest_side(pa).is_none_or(|side| {
                    let both: Vec<Vec3> = instances[a]
                        .gaussians
                        .means
                        .iter()
                        .chain(&instances[b].gaussians.means)
                        .copied()
                        .collect();
                    let union = fit_object_box(&both, DEFAULT_TRIM);
                    union.size.x.max(union.size.y) <= FRAGMENT_SIDE_MARGIN * side
                })
        });
        self.retain_marked(&keep);
        folded
    }

    /// Every pair of live instances with at least one of them `touched` (changed since the pair
    /// was last judged), oldest first (so everything folds into the instance the user saw
    /// first): where `one_object` says so, the younger is absorbed into the older and marked dead
    /// in `keep`. Then pass after pass over the pairs of the last pass's survivors (they changed
    /// after some of their pairs were judged) until a pass folds nothing. Point footprints are
    /// built only when `one_object` asks for them, and again after their instance absorbs
    /// another; bounds and boxes afresh in the pass after. Returns (absorbed, survivor) id pairs.
    fn fold_pairs(
        &mut self,
        keep: &mut [bool],
        touched: &[bool],
        mut one_object: impl FnMut(&[Instance], &mut Footprints, usize, usize) -> bool,
    ) -> Vec<(String, String)> {
        let p = self.params;
        let n = self.instances.len();
        let mut footprints = Footprints {
            voxel: p.voxel,
            built: (0..n).map(|_| None).collect(),
            bounds: self
                .instances
                .iter()
                .map(|i| bounds(&i.gaussians))
                .collect(),
            spread: (0..n).map(|_| None).collect(),
            boxes: (0..n).map(|_| None).collect(),
        };
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by_key(|&i| birth_order(&self.instances[i]));
        let mut folded = Vec::new();
        let mut touched = touched.to_vec();
        loop {
            let mut grew = vec![false; n];
            for (position, &a) in order.iter().enumerate() {
                if !keep[a] {
                    continue;
                }
                for &b in &order[position + 1..] {
                    if !keep[b] || !(touched[a] || touched[b]) {
                        continue;
                    }
                    if one_object(&self.instances, &mut footprints, a, b) {
                        let absorbed = self.instances[b].clone();
                        self.instances[a].absorb(&absorbed, p);
                        footprints.built[a] = None;
                        footprints.spread[a] = None;
                        let ((lo_a, hi_a), (lo_b, hi_b)) =
                            (footprints.bounds[a], footprints.bounds[b]);
                        footprints.bounds[a] = (lo_a.min(lo_b), hi_a.max(hi_b));
                        keep[b] = false;
                        grew[a] = true;
                        folded.push((absorbed.id, self.instances[a].id.clone()));
                    }
                }
            }
            if !grew.contains(&true) {
                return folded;
            }
            for (k, &changed) in grew.iter().enumerate() {
                if changed {
                    footprints.bounds[k] = bounds(&self.instances[k].gaussians);
                    footprints.boxes[k] = None;
                }
            }
            touched = grew;
        }
    }

    /// Fold instances that are one object (similar prototypes and overlapping boxes, or two
    /// objects' boxes filling one space, [`ONE_SPACE_IOU`]) into the oldest of them; `keep` marks
    /// the instances still alive and is updated. Returns (absorbed, survivor) id pairs.
    fn fold_duplicates(
        &mut self,
        keep: &mut [bool],
        touched: &[bool],
        same_kind: &dyn Fn(&[f32], &[f32]) -> bool,
    ) -> Vec<(String, String)> {
        let p = self.params;
        let is_object = |prototype: &[f32]| names_an_object(same_kind, prototype);
        self.fold_pairs(keep, touched, |instances, footprints, a, b| {
            let (pa, pb) = (&instances[a].prototype, &instances[b].prototype);
            let similar = !pa.is_empty()
                && !pb.is_empty()
                && cosine(pa, pb) >= p.duplicate_similarity
                && same_kind(pa, pb);
            if similar && p.duplicate_iou <= 0.0 {
                // Prototypes alone decide.
                return true;
            }
            let objects = similar || (is_object(pa) && is_object(pb));
            if !objects || footprints.far_apart(a, b) {
                return false;
            }
            let box_a = footprints.oriented_box(instances, a);
            let box_b = footprints.oriented_box(instances, b);
            let iou = box_a.iou(&box_b);
            if iou >= ONE_SPACE_IOU {
                return true;
            }
            // Point footprints only where boxes alone do not decide.
            similar && (iou >= p.duplicate_iou || footprints.overlap(instances, a, b) >= 0.5)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;
    use rand::{Rng, SeedableRng};

    /// Points along a random segment with a little spread: thin diagonal sets are where a fitted
    /// box pokes out of the points' axis-aligned bounds the most.
    fn rod(rng: &mut rand_chacha::ChaCha8Rng, centre: Vec3) -> Gaussians {
        let mut g = Gaussians::with_dims(0, 0);
        let half = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            0.0,
        ) * rng.random_range(0.05..1.5);
        for k in 0..60 {
            let t = k as f32 / 59.0 * 2.0 - 1.0;
            let jitter = Vec3::new(
                rng.random_range(-0.02..0.02),
                rng.random_range(-0.02..0.02),
                rng.random_range(0.0..0.3),
            );
            let p = centre + half * t + jitter;
            g.push(
                p,
                0.9,
                Vec3::splat(0.01),
                Quat::IDENTITY,
                Vec3::splat(0.5),
                &[],
                &[],
            );
        }
        g
    }

    #[test]
    fn no_two_objects_of_the_training_rooms_fill_one_space() {
        // ONE_SPACE_IOU against the data: the largest 3D IoU of two objects' true boxes in the
        // first 200 training rooms is a small share of it.
        let mut largest = 0.0f64;
        for room in super::super::amodal::training_rooms() {
            for (k, (_, a)) in room.iter().enumerate() {
                for (_, b) in &room[k + 1..] {
                    largest = largest.max(a.iou(b));
                }
            }
        }
        assert!(largest > 0.0, "some objects touch (a pillow on a bed)");
        assert!(largest < ONE_SPACE_IOU / 4.0, "{largest}");
    }

    #[test]
    fn fragments_born_in_one_window_fold_into_the_lower_id_however_often_the_other_was_seen() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let piece = rod(&mut rng, Vec3::new(2.0, 2.6, 0.4));
        let fragment = |id: &str, observations: u32| Instance {
            id: id.to_owned(),
            gaussians: piece.clone(),
            prototype: vec![1.0, 0.0, 0.0],
            prototype_weight: 1.0,
            confidence: 0.5,
            observations,
            first_seen_nanos: 1_000,
            last_seen_nanos: 2_000,
            viewpoint: None,
            viewpoint_weight: 0.0,
            range_noise_m: 0.0,
            range_noise_weight: 0.0,
        };
        // Two pieces of one chair born in one window; the younger was seen again by the next
        // window, the older is the one the map listed. Ids compare in birth order (010 > 009).
        for (older, younger) in [
            ("inst_000002", "inst_000003"),
            ("inst_000009", "inst_000010"),
        ] {
            let mut map = SceneMap::new(FusionParams::default());
            map.instances = vec![fragment(younger, 2), fragment(older, 1)];
            let folded = map.fold_fragments(&|_: &[f32], _: &[f32]| true);
            assert_eq!(folded, vec![(younger.to_owned(), older.to_owned())]);
            assert_eq!(map.instances.len(), 1);
            assert_eq!(map.instances[0].id, older);
        }
    }

    #[test]
    fn a_leg_needs_finite_bounds_an_upright_shape_and_a_surface_over_it() {
        let top = (Vec3::new(-0.4, -0.3, 0.72), Vec3::new(0.4, 0.3, 0.75));
        let leg = (Vec3::new(0.3, 0.2, 0.0), Vec3::new(0.35, 0.25, 0.7));
        assert!(is_leg_of(leg, top));
        assert!(!is_leg_of(top, leg), "the top is no leg of its leg");
        let empty = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let nan = (Vec3::splat(f32::NAN), Vec3::splat(f32::NAN));
        for bad in [empty, nan] {
            assert!(!is_leg_of(bad, top) && !is_leg_of(leg, bad));
        }
        // A point (one Gaussian) and a flat stub are not upright; a leg ending a hand below the
        // top carries something else; a leg poking out beside the top is not under it.
        let point = (Vec3::new(0.3, 0.2, 0.5), Vec3::new(0.3, 0.2, 0.5));
        let stub = (Vec3::new(0.3, 0.2, 0.0), Vec3::new(0.35, 0.25, 0.05));
        let short = (Vec3::new(0.3, 0.2, 0.0), Vec3::new(0.35, 0.25, 0.5));
        let beside = (Vec3::new(0.52, 0.2, 0.0), Vec3::new(0.57, 0.25, 0.7));
        // A monitor standing on a desk whose points reach the floor: thin, upright, under the
        // desk's top and ending near the top of its bounds (the monitor's own), but it does not
        // reach down.
        let desk = (Vec3::new(-0.4, -0.3, 0.0), Vec3::new(0.4, 0.3, 1.2));
        let monitor = (Vec3::new(-0.25, 0.0, 0.75), Vec3::new(0.25, 0.05, 1.2));
        assert!(!is_leg_of(monitor, desk));
        assert!(is_leg_of(
            (Vec3::new(-0.25, 0.0, 0.0), Vec3::new(0.25, 0.05, 1.2)),
            desk
        ));
        for not_a_leg in [point, stub, short, beside] {
            assert!(!is_leg_of(not_a_leg, top), "{not_a_leg:?}");
        }
    }

    #[test]
    fn a_headboard_folds_into_its_bed_but_not_into_the_twin_bed_beside_it() {
        // The foot end of a bed seen (x 5.1-6.6), its headboard 0.85 m beyond (x 7.45-7.6),
        // wider than the part of the mattress seen, rising above it.
        let mattress = (Vec3::new(5.1, 1.9, 0.0), Vec3::new(6.6, 2.6, 0.48));
        let headboard = (Vec3::new(7.45, 1.1, 0.48), Vec3::new(7.6, 3.0, 1.2));
        assert!(is_back_of(headboard, mattress, 0.0));
        assert!(
            !is_back_of(mattress, headboard, 0.0),
            "the mattress is no back"
        );
        // A twin bed beside it (y 3.4-5.0): the headboard lies along its own bed, not this one.
        let twin = (Vec3::new(5.6, 3.4, 0.0), Vec3::new(7.5, 5.0, 0.48));
        assert!(!is_back_of(headboard, twin, 0.0));
        // A chair in the row behind another: its back is no higher than the other chair.
        let chair = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.45, 0.45, 0.9));
        let back_of_the_chair_behind = (Vec3::new(0.0, 0.7, 0.45), Vec3::new(0.45, 0.75, 0.9));
        assert!(!is_back_of(back_of_the_chair_behind, chair, 0.0));
        // Farther than the gap, in the seat's middle, or without finite bounds: no back.
        let far = (Vec3::new(7.7, 1.1, 0.48), Vec3::new(7.85, 3.0, 1.2));
        let across_the_middle = (Vec3::new(5.8, 1.1, 0.48), Vec3::new(5.95, 3.0, 1.2));
        assert!(!is_back_of(far, mattress, 0.0) && !is_back_of(across_the_middle, mattress, 0.0));
        let nan = (Vec3::splat(f32::NAN), Vec3::splat(f32::NAN));
        let empty = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for bad in [nan, empty] {
            assert!(!is_back_of(bad, mattress, 0.0) && !is_back_of(headboard, bad, 0.0));
        }
    }

    #[test]
    fn a_noisy_back_is_judged_by_its_central_points_less_the_noise_and_degenerate_sets_are_no_back()
    {
        // 100 points along x (0..99 cm) and two non-finite ones: 5% each side left out.
        let mut points: Vec<Vec3> = (0..100)
            .map(|i| Vec3::new(i as f32 * 0.01, 0.0, 0.0))
            .collect();
        points.push(Vec3::NAN);
        points.push(Vec3::new(f32::INFINITY, 0.0, 0.0));
        let (lo, hi) = share_bounds(&points, BACK_SPREAD_SHARE);
        assert!(
            (lo.x - 0.05).abs() < 1e-6 && (hi.x - 0.94).abs() < 1e-6,
            "{lo} {hi}"
        );
        let single = share_bounds(&[Vec3::ONE], BACK_SPREAD_SHARE);
        assert_eq!(single, (Vec3::ONE, Vec3::ONE));
        let empty = share_bounds(&[Vec3::NAN], BACK_SPREAD_SHARE);
        assert_eq!(empty, (Vec3::INFINITY, Vec3::NEG_INFINITY));
        // A headboard 0.9 m deep through noise: a back only with the noise's spread allowed for.
        let mattress = (Vec3::new(5.1, 1.9, 0.0), Vec3::new(6.6, 2.6, 0.48));
        let spread_headboard = (Vec3::new(7.1, 1.1, 0.48), Vec3::new(8.0, 3.0, 1.2));
        assert!(!is_back_of(spread_headboard, mattress, 0.0));
        assert!(is_back_of(spread_headboard, mattress, 0.6));
        // Noise never makes a back of what is no back: the mattress, or a chair's neighbour.
        assert!(!is_back_of(mattress, spread_headboard, 0.6));
        // A lamp's shade above another lamp, 21 cm across each way: the noise makes it thin,
        // never long.
        let lamp = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.25, 0.25, 0.52));
        let shade = (Vec3::new(0.02, 0.3, 0.7), Vec3::new(0.234, 0.51, 0.83));
        assert!(!is_back_of(shade, lamp, 0.18));
        for bad in [f32::NAN, -0.1, f32::INFINITY] {
            assert!(!is_back_of(spread_headboard, mattress, bad), "{bad}");
        }
        assert!(!is_back_of(empty, mattress, 0.6));
    }

    #[test]
    fn pairs_judged_far_apart_never_have_intersecting_boxes_or_touching_footprints() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (mut pruned, mut trials) = (0, 0);
        for _ in 0..400 {
            let offset = Vec3::new(
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
                0.0,
            );
            let (a, b) = (rod(&mut rng, Vec3::ZERO), rod(&mut rng, offset));
            let footprints = Footprints {
                voxel: 0.05,
                built: vec![None, None],
                bounds: vec![bounds(&a), bounds(&b)],
                spread: vec![None, None],
                boxes: vec![None, None],
            };
            if !footprints.far_apart(0, 1) {
                continue;
            }
            pruned += 1;
            let (box_a, box_b) = (
                OrientedBox::fit(&a.means, crate::recon::boxes::DEFAULT_TRIM),
                OrientedBox::fit(&b.means, crate::recon::boxes::DEFAULT_TRIM),
            );
            assert_eq!(box_a.iou(&box_b), 0.0, "boxes of a far pair intersect");
            let (fa, fb) = (Footprint::new(&a, 0.05), Footprint::new(&b, 0.05));
            assert_eq!(fa.overlap(&fb, 1.5 * fa.spacing.max(fb.spacing)), 0.0);
            trials += 1;
        }
        // The check must have pruned something, and not everything.
        assert!(pruned > 50 && pruned < 400, "{pruned} of 400 pruned");
        assert_eq!(trials, pruned);
    }
}
