//! The persistent instance map and its scene graph (DESIGN §5.6).
//!
//! Each window pass yields instances (Gaussians plus a semantic prototype). [`SceneMap::fuse`]
//! associates them with the persistent instances by 3D overlap (nearest-neighbour ratio) plus
//! prototype similarity with an optimal assignment (Kuhn–Munkres, `pathfinding`); matched ones
//! merge (voxel-downsampled Gaussians, count-weighted prototype), unmatched ones are born, and
//! persistent instances that the window should have seen but did not lose confidence and die.
//! Memory stays bounded: Gaussians per instance and keyframes are capped, and instances beyond a
//! clearing radius from the robot are dropped. [`SceneMap::graph`] derives nodes and edges.

pub mod persist;

use std::collections::{HashMap, VecDeque};

use glam::{DVec2, DVec3, Vec3};
use pathfinding::prelude::{kuhn_munkres, Matrix};

use crate::recon::camera::Camera;
use crate::recon::gaussians::{voxel_downsample, Gaussians};
use crate::recon::raster::{render, RasterSettings};
use crate::recon::Rigid;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GraphError {
    #[error("window instance {0}: {1}")]
    BadInstance(usize, String),
    #[error("rendering a keyframe: {0}")]
    Render(String),
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

/// A window view as fusion sees it: the keyframe and the depth the window observed there (sensor
/// or rendered), used to decide which persistent instances it should have seen.
#[derive(Debug, Clone, PartialEq)]
pub struct WindowView {
    pub keyframe: Keyframe,
    pub depth: Vec<f32>,
}

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
}

impl Instance {
    pub fn bounds(&self) -> (Vec3, Vec3) {
        bounds(&self.gaussians)
    }

    pub fn center(&self) -> Vec3 {
        let (lo, hi) = self.bounds();
        (lo + hi) / 2.0
    }

    /// Add Gaussians (voxel-merged, capped) and a prototype observed with `weight` (count-weighted
    /// mean).
    fn merge(&mut self, gaussians: &Gaussians, prototype: &[f32], weight: f64, p: FusionParams) {
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
    fn absorb(&mut self, other: &Instance, p: FusionParams) {
        self.merge(
            &other.gaussians,
            &other.prototype,
            other.prototype_weight,
            p,
        );
        self.confidence = self.confidence.max(other.confidence);
        self.observations += other.observations;
        self.first_seen_nanos = self.first_seen_nanos.min(other.first_seen_nanos);
        self.last_seen_nanos = self.last_seen_nanos.max(other.last_seen_nanos);
    }
}

fn bounds(g: &Gaussians) -> (Vec3, Vec3) {
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
    /// Confidence of a new instance, gained per match, and lost per window that should have
    /// seen it but did not.
    pub birth_confidence: f32,
    pub confirm_gain: f32,
    pub miss_penalty: f32,
    /// Fraction of an instance's Gaussians that must be visible (in the image, not occluded) for
    /// the window to count as having been able to see it.
    pub visible_fraction: f32,
    /// Depth tolerance of the occlusion test (metres).
    pub depth_tolerance: f32,
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
        }
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
fn capped(g: Gaussians, voxel: f32, cap: usize) -> Gaussians {
    let merged = voxel_downsample(&g, voxel).unwrap_or(g);
    if merged.len() <= cap || cap == 0 {
        return merged;
    }
    let stride = merged.len().div_ceil(cap);
    let mut out = Gaussians::with_dims(merged.embedding_dim, merged.extra_dim);
    for i in (0..merged.len()).step_by(stride) {
        out.push(
            merged.means[i],
            merged.opacities[i],
            merged.scales[i],
            merged.rotations[i],
            merged.colors[i],
            merged.embedding(i),
            &merged.extra[i * merged.extra_dim..(i + 1) * merged.extra_dim],
        );
    }
    out
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

    /// The scene graph over the `views` newest keyframes.
    pub fn graph(&self, views: usize, max_edge_distance: f32) -> Result<SceneGraph, GraphError> {
        let keyframes: Vec<&Keyframe> = self.keyframes.iter().rev().take(views).collect();
        // One depth render of the whole map per keyframe: the occlusion reference.
        let mut all = Gaussians::with_dims(0, 0);
        let mut owner = Vec::new();
        for (k, instance) in self.instances.iter().enumerate() {
            let mut g = instance.gaussians.clone();
            g.embedding_dim = 0;
            g.embeddings.clear();
            g.extra_dim = 0;
            g.extra.clear();
            all.extend(&g);
            owner.extend(std::iter::repeat_n(k, instance.gaussians.len()));
        }
        let depths: Vec<Vec<f32>> = keyframes
            .iter()
            .map(|kf| {
                render(
                    &all,
                    &[],
                    0,
                    &kf.camera,
                    &kf.world_from_camera.inverse(),
                    &RasterSettings::default(),
                )
                .map(|r| r.depth)
                .map_err(|e| GraphError::Render(e.to_string()))
            })
            .collect::<Result<_, _>>()?;
        let nodes: Vec<GraphNode> = self
            .instances
            .iter()
            .map(|instance| {
                let (lo, hi) = instance.bounds();
                let extent = hi - lo;
                let views = keyframes
                    .iter()
                    .zip(&depths)
                    .map(|(kf, depth)| node_view(instance, kf, depth, self.params.depth_tolerance))
                    .collect();
                GraphNode {
                    id: instance.id.clone(),
                    prototype: instance.prototype.clone(),
                    center: ((lo + hi) / 2.0).to_array(),
                    extent: extent.to_array(),
                    volume: extent.x * extent.y * extent.z,
                    confidence: instance.confidence,
                    views,
                }
            })
            .collect();
        let mut edges = Vec::new();
        for a in 0..nodes.len() {
            for b in a + 1..nodes.len() {
                let (na, nb) = (&nodes[a], &nodes[b]);
                let ca = Vec3::from_array(na.center);
                let cb = Vec3::from_array(nb.center);
                let distance = ca.distance(cb);
                if distance > max_edge_distance {
                    continue;
                }
                let views = na
                    .views
                    .iter()
                    .zip(&nb.views)
                    .map(|(va, vb)| edge_view(va, vb))
                    .collect();
                edges.push(GraphEdge {
                    source: a,
                    target: b,
                    distance,
                    height_difference: ca.z - cb.z,
                    size_ratio: na.volume.max(1e-9) / nb.volume.max(1e-9),
                    views,
                });
            }
        }
        Ok(SceneGraph {
            keyframe_stamps: keyframes.iter().map(|k| k.stamp_nanos).collect(),
            nodes,
            edges,
        })
    }
}

/// A node of the scene graph.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphNode {
    pub id: String,
    pub prototype: Vec<f32>,
    pub center: [f32; 3],
    pub extent: [f32; 3],
    pub volume: f32,
    pub confidence: f32,
    /// Per keyframe of the graph.
    pub views: Vec<NodeView>,
}

/// How a node appears in one keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeView {
    /// Projected 2D box (x0, y0, x1, y1) of the instance's Gaussians in the image, clipped; `None`
    /// when no Gaussian projects into the image.
    pub bbox: Option<[f32; 4]>,
    /// ν: fraction of the instance's Gaussians in the image and not occluded by the rendered map.
    pub visibility: f32,
}

/// An edge between nodes `source` and `target` (indices into `nodes`).
#[derive(Debug, Clone, PartialEq)]
pub struct GraphEdge {
    pub source: usize,
    pub target: usize,
    pub distance: f32,
    /// Centre height of source minus target.
    pub height_difference: f32,
    /// Volume of source over target.
    pub size_ratio: f32,
    pub views: Vec<EdgeView>,
}

/// An edge in one keyframe (absent boxes give `None`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeView {
    /// Distance between the projected box centres (pixels).
    pub distance: Option<f32>,
    /// Direction from source to target in the image, radians (0 = right, π/2 = down).
    pub direction: Option<f32>,
    /// IoU of the projected boxes.
    pub overlap: Option<f32>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct SceneGraph {
    pub keyframe_stamps: Vec<i64>,
    pub nodes: Vec<GraphNode>,
    pub edges: Vec<GraphEdge>,
}

fn node_view(instance: &Instance, keyframe: &Keyframe, depth: &[f32], tolerance: f32) -> NodeView {
    let camera_from_world = keyframe.world_from_camera.inverse();
    let camera = &keyframe.camera;
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    let mut visible = 0usize;
    for m in &instance.gaussians.means {
        let p: DVec3 = camera_from_world.transform_point(m.as_dvec3());
        let Some(pixel) = camera.project(p) else {
            continue;
        };
        if pixel.x < -0.5 || pixel.y < -0.5 || pixel.x > w - 0.5 || pixel.y > h - 0.5 {
            continue;
        }
        lo = lo.min(pixel);
        hi = hi.max(pixel);
        let (u, v) = (
            (pixel.x.round() as usize).min(camera.width as usize - 1),
            (pixel.y.round() as usize).min(camera.height as usize - 1),
        );
        let rendered = depth[v * camera.width as usize + u];
        if rendered <= 0.0 || (p.z as f32) <= rendered + tolerance {
            visible += 1;
        }
    }
    NodeView {
        bbox: lo
            .x
            .is_finite()
            .then_some([lo.x as f32, lo.y as f32, hi.x as f32, hi.y as f32]),
        visibility: visible as f32 / instance.gaussians.len().max(1) as f32,
    }
}

fn edge_view(a: &NodeView, b: &NodeView) -> EdgeView {
    match (a.bbox, b.bbox) {
        (Some(ba), Some(bb)) => {
            let ca = [(ba[0] + ba[2]) / 2.0, (ba[1] + ba[3]) / 2.0];
            let cb = [(bb[0] + bb[2]) / 2.0, (bb[1] + bb[3]) / 2.0];
            let (dx, dy) = (cb[0] - ca[0], cb[1] - ca[1]);
            let ix = (ba[2].min(bb[2]) - ba[0].max(bb[0])).max(0.0);
            let iy = (ba[3].min(bb[3]) - ba[1].max(bb[1])).max(0.0);
            let area = |b: [f32; 4]| (b[2] - b[0]).max(0.0) * (b[3] - b[1]).max(0.0);
            let union = area(ba) + area(bb) - ix * iy;
            EdgeView {
                distance: Some((dx * dx + dy * dy).sqrt()),
                direction: Some(dy.atan2(dx)),
                overlap: Some(if union > 0.0 { ix * iy / union } else { 0.0 }),
            }
        }
        _ => EdgeView {
            distance: None,
            direction: None,
            overlap: None,
        },
    }
}
