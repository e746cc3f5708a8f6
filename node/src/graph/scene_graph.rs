//! The scene graph derived from the map: nodes (prototype, centre, extent, volume, per keyframe
//! projected box and visibility) and edges (distance, height difference, size ratio, per keyframe
//! projected distance, direction and overlap), ARCHITECTURE.md §4.

use glam::{DVec2, DVec3, Vec3};
use rayon::prelude::*;

use super::error::GraphError;
use super::fusion::SceneMap;
use super::instance::Instance;
use crate::frame::Keyframe;
use crate::recon::gaussians::Gaussians;
use crate::recon::raster::{render_labels, LabelRender, RasterSettings};

impl SceneMap {
    /// The scene graph over the `views` newest keyframes.
    pub fn graph(&self, views: usize, max_edge_distance: f32) -> Result<SceneGraph, GraphError> {
        self.graph_with_renders(views, max_edge_distance)
            .map(|(graph, _)| graph)
    }

    /// The scene graph and, per keyframe of the graph (newest first), the whole map rendered
    /// there with each pixel's instance (index into `instances`): depth is the occlusion
    /// reference, labels are the map's instance masks in that view.
    pub fn graph_with_renders(
        &self,
        views: usize,
        max_edge_distance: f32,
    ) -> Result<(SceneGraph, Vec<LabelRender>), GraphError> {
        let keyframes: Vec<&Keyframe> = self.keyframes.iter().rev().take(views).collect();
        // One render of the whole map per keyframe, labelled by instance.
        let mut all = Gaussians::with_dims(0, 0);
        let mut owner = Vec::new();
        for (k, instance) in self.instances.iter().enumerate() {
            all.extend_geometry(&instance.gaussians);
            owner.extend(std::iter::repeat_n(k as u32, instance.gaussians.len()));
        }
        let renders: Vec<LabelRender> = keyframes
            .iter()
            .map(|kf| {
                render_labels(
                    &all,
                    &owner,
                    &kf.camera,
                    &kf.world_from_camera.inverse(),
                    &RasterSettings::default(),
                )
                .map_err(|e| GraphError::Render(e.to_string()))
            })
            .collect::<Result<_, _>>()?;
        // Every instance's points projected into every view: one instance per thread.
        let nodes: Vec<GraphNode> = self
            .instances
            .par_iter()
            .map(|instance| {
                let (lo, hi) = instance.bounds();
                let extent = hi - lo;
                let views = keyframes
                    .iter()
                    .zip(&renders)
                    .map(|(kf, r)| node_view(instance, kf, &r.depth, self.params.depth_tolerance))
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
        let graph = SceneGraph {
            keyframe_stamps: keyframes.iter().map(|k| k.stamp_nanos).collect(),
            nodes,
            edges,
        };
        Ok((graph, renders))
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

#[derive(Debug, Clone, Default, PartialEq)]
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
