//! Fusion: associate a window's instances with the persistent ones (3D overlap plus prototype
//! similarity, Kuhn–Munkres), merge or give birth, fold duplicates, and let instances that should
//! have been seen lose confidence and die.

use std::collections::{HashMap, VecDeque};

use glam::Vec3;
use pathfinding::prelude::{kuhn_munkres, Matrix};

use super::error::GraphError;
use super::instance::{bounds, capped, cosine, FusionParams, Instance};
use crate::frame::{Keyframe, WindowInstance, WindowView};
use crate::recon::gaussians::Gaussians;

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
        let apart =
            (0..3).any(|a| self.lo[a] - radius > other.hi[a] || other.lo[a] - radius > self.hi[a]);
        if apart {
            return 0.0;
        }
        let (small, large) = if self.points.len() <= other.points.len() {
            (self, other)
        } else {
            (other, self)
        };
        let cell = |p: Vec3| {
            (
                (p.x / radius).floor() as i32,
                (p.y / radius).floor() as i32,
                (p.z / radius).floor() as i32,
            )
        };
        let mut grid: HashMap<(i32, i32, i32), Vec<Vec3>> = HashMap::new();
        for p in &large.points {
            grid.entry(cell(*p)).or_default().push(*p);
        }
        let r2 = radius * radius;
        let hits = small
            .points
            .iter()
            .filter(|p| {
                let (x, y, z) = cell(**p);
                (-1..=1).any(|dx| {
                    (-1..=1).any(|dy| {
                        (-1..=1).any(|dz| {
                            grid.get(&(x + dx, y + dy, z + dz)).is_some_and(|cell| {
                                cell.iter().any(|q| q.distance_squared(**p) <= r2)
                            })
                        })
                    })
                })
            })
            .count();
        hits as f32 / small.points.len().max(1) as f32
    }
}

/// Fraction of `g`'s Gaussians that `view` sees (inside the image, in front, not behind the
/// observed depth by more than `tolerance`), and the number that project into the image.
fn visible_fraction(g: &Gaussians, view: &WindowView, tolerance: f32) -> (f32, usize) {
    let camera_from_world = view.keyframe.world_from_camera.inverse();
    let camera = &view.keyframe.camera;
    let width = camera.width as usize;
    let (mut visible, mut inside) = (0usize, 0usize);
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
        if !observed.is_finite() || observed <= 0.0 || (p.z as f32) <= observed + tolerance {
            visible += 1;
        }
    }
    (visible as f32 / g.len().max(1) as f32, inside)
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
        let p = self.params;
        for (i, w) in window.iter().enumerate() {
            w.gaussians
                .validate()
                .map_err(|e| GraphError::BadInstance(i, e.to_string()))?;
            if w.gaussians.is_empty() {
                return Err(GraphError::BadInstance(i, "no Gaussians".into()));
            }
        }
        let mut report = FusionReport::default();
        // Association scores: geometry (nearest-neighbour overlap within a radius that follows
        // the point spacing) and semantics (prototype cosine), gated.
        let window_footprints: Vec<Footprint> = window
            .iter()
            .map(|w| Footprint::new(&w.gaussians, p.voxel))
            .collect();
        let map_footprints: Vec<Footprint> = self
            .instances
            .iter()
            .map(|m| Footprint::new(&m.gaussians, p.voxel))
            .collect();
        let scale = 1_000_000.0f32;
        let (rows, cols) = (window.len(), self.instances.len() + window.len());
        let mut pairs = vec![None; rows];
        // Persistent instances that also pass the gate for a window instance matched elsewhere:
        // duplicates of one object (born when an earlier view overlapped too little).
        let mut duplicates: Vec<Vec<usize>> = vec![Vec::new(); rows];
        if rows > 0 && !self.instances.is_empty() {
            // Columns: every persistent instance, plus one "new instance" column per row so that
            // rows ≤ columns and birth is always possible (score 0).
            let mut weights = Matrix::new(rows, cols, 0i64);
            for (i, wf) in window_footprints.iter().enumerate() {
                for (j, mf) in map_footprints.iter().enumerate() {
                    let radius = 1.5 * wf.spacing.max(mf.spacing);
                    let overlap = wf.overlap(mf, radius);
                    // Without semantics (no semantic model yet), geometry alone decides.
                    let (a, b) = (&window[i].prototype, &self.instances[j].prototype);
                    let similarity = (!a.is_empty() && !b.is_empty()).then(|| cosine(a, b));
                    if overlap >= p.min_overlap && similarity.is_none_or(|s| s >= p.min_similarity)
                    {
                        let score = match similarity {
                            Some(similarity) => {
                                p.geometry_weight * overlap + (1.0 - p.geometry_weight) * similarity
                            }
                            None => overlap,
                        };
                        weights[(i, j)] = (score * scale) as i64;
                    }
                }
            }
            let (_, assignment) = kuhn_munkres(&weights);
            for (i, &j) in assignment.iter().enumerate() {
                if j < self.instances.len() && weights[(i, j)] > 0 {
                    pairs[i] = Some(j);
                    duplicates[i] = (0..self.instances.len())
                        .filter(|&other| other != j && weights[(i, other)] > 0)
                        .filter(|&other| !assignment.contains(&other))
                        .collect();
                }
            }
        }
        let mut matched = vec![false; self.instances.len()];
        let mut absorbed = vec![false; self.instances.len()];
        for (i, w) in window.into_iter().enumerate() {
            match pairs[i] {
                Some(j) => {
                    matched[j] = true;
                    // Fold duplicates into the oldest of them (ids only ever grow).
                    let mut group: Vec<usize> = std::iter::once(j)
                        .chain(duplicates[i].iter().copied().filter(|&d| !absorbed[d]))
                        .collect();
                    group.sort_by_key(|&k| self.instances[k].first_seen_nanos);
                    let j = group[0];
                    for &d in &group[1..] {
                        absorbed[d] = true;
                        matched[d] = true;
                        let duplicate = self.instances[d].clone();
                        report
                            .absorbed
                            .push((duplicate.id.clone(), self.instances[j].id.clone()));
                        self.instances[j].absorb(&duplicate, p);
                    }
                    matched[j] = true;
                    let m = &mut self.instances[j];
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
                    self.instances.push(Instance {
                        id,
                        gaussians: capped(w.gaussians, p.voxel, p.max_gaussians_per_instance),
                        prototype: w.prototype,
                        prototype_weight: w.support.max(1) as f64,
                        confidence: p.birth_confidence,
                        observations: 1,
                        first_seen_nanos: stamp_nanos,
                        last_seen_nanos: stamp_nanos,
                    });
                    report.born += 1;
                }
            }
        }
        // Unmatched instances that some window view should have seen lose confidence.
        let mut keep: Vec<bool> = (0..self.instances.len())
            .map(|j| j >= absorbed.len() || !absorbed[j])
            .collect();
        for (j, instance) in self.instances.iter_mut().enumerate() {
            if j >= matched.len() || matched[j] {
                continue;
            }
            let expected = views.iter().any(|view| {
                let (fraction, inside) =
                    visible_fraction(&instance.gaussians, view, p.depth_tolerance);
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
        // the same window, or parts that grew together): fold them, younger into older.
        for (absorbed, survivor) in self.fold_duplicates(&mut keep) {
            report.absorbed.push((absorbed, survivor));
        }
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
        let mut index = 0;
        self.instances.retain(|_| {
            index += 1;
            keep[index - 1]
        });
        for view in views {
            self.keyframes.push_back(view.keyframe.clone());
        }
        while self.keyframes.len() > p.max_keyframes {
            self.keyframes.pop_front();
        }
        Ok(report)
    }

    /// Fold instances that are one object (similar prototypes, overlapping boxes) into the oldest
    /// of them; `keep` marks the instances still alive and is updated. Returns (absorbed,
    /// survivor) id pairs.
    fn fold_duplicates(&mut self, keep: &mut [bool]) -> Vec<(String, String)> {
        let p = self.params;
        let boxes: Vec<_> = self.instances.iter().map(|i| i.oriented_box()).collect();
        let mut folded = Vec::new();
        let n = self.instances.len();
        // Point footprints only where boxes alone do not decide, each built once (again after its
        // instance absorbs another).
        let mut footprints: Vec<Option<Footprint>> = (0..n).map(|_| None).collect();
        // Oldest first, so every duplicate folds into the instance the user saw first.
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by_key(|&i| (self.instances[i].first_seen_nanos, i));
        for (position, &a) in order.iter().enumerate() {
            if !keep[a] {
                continue;
            }
            for &b in &order[position + 1..] {
                if !keep[b] {
                    continue;
                }
                let (pa, pb) = (&self.instances[a].prototype, &self.instances[b].prototype);
                let similar =
                    !pa.is_empty() && !pb.is_empty() && cosine(pa, pb) >= p.duplicate_similarity;
                if !similar {
                    continue;
                }
                let duplicate = boxes[a].iou(&boxes[b]) >= p.duplicate_iou || {
                    for k in [a, b] {
                        if footprints[k].is_none() {
                            footprints[k] =
                                Some(Footprint::new(&self.instances[k].gaussians, p.voxel));
                        }
                    }
                    match (&footprints[a], &footprints[b]) {
                        (Some(fa), Some(fb)) => {
                            fa.overlap(fb, 1.5 * fa.spacing.max(fb.spacing)) >= 0.5
                        }
                        _ => false,
                    }
                };
                if duplicate {
                    let absorbed = self.instances[b].clone();
                    self.instances[a].absorb(&absorbed, p);
                    footprints[a] = None;
                    keep[b] = false;
                    folded.push((absorbed.id, self.instances[a].id.clone()));
                }
            }
        }
        folded
    }
}
