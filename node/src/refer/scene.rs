//! What a query reads: a snapshot of the map taken after each fused window, so queries never hold
//! the map's lock while they parse, embed and reason. Per object instance (structure excluded):
//! its names as a distribution over the vocabulary, its box, mean colour and visibility ν in the
//! newest keyframes; per keyframe, its pose and the map's rendered depth (the occlusion reference
//! masks are cut against).

use std::collections::HashMap;
use std::sync::Arc;

use glam::DVec3;

use crate::frame::{Keyframe, MeasuredDepth};
use crate::graph::listing::object_list_with_tentative;
use crate::graph::{GraphError, SceneGraph, SceneMap};
use crate::group::semantics::Vocabulary;
use crate::observations::Observations;
use crate::recon::boxes::OrientedBox;
use crate::recon::gaussians::Gaussians;

/// Keyframes a snapshot keeps (newest first): what visibility and masks are computed in.
pub const SNAPSHOT_VIEWS: usize = 4;
/// A pixel belongs to a mask where the instance renders at least this opaque.
pub const MASK_ALPHA: f32 = 0.5;
/// Scene-graph edges join instances whose centres are at most this far apart (metres): a room's
/// neighbours. Referring relations read boxes, not edges; the edges are for the published graph.
pub const SNAPSHOT_EDGE_DISTANCE_M: f32 = 3.0;

/// One object instance as a query sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferNode {
    pub id: String,
    /// p(phrase | instance) over the vocabulary's phrases, in the vocabulary's order (empty: the
    /// instance has no semantics).
    pub names: Vec<f32>,
    /// Its best name ("" without semantics).
    pub label: String,
    pub bbox: OrientedBox,
    /// Axis-aligned bounds of `bbox`.
    pub lo: DVec3,
    pub hi: DVec3,
    /// Mean colour of its Gaussians (RGB, 0-1).
    pub color: [f32; 3],
    /// ν: the largest fraction of its Gaussians visible (in the image, unoccluded) in any kept
    /// keyframe.
    pub visibility: f32,
    pub confidence: f32,
    pub gaussians: usize,
    /// A tentative candidate, not in the published object list (a small piece seen by one window
    /// or named unsurely, [`crate::group::semantics::Vocabulary::is_tentative`]): a query answers
    /// it only where no listed instance fits.
    pub tentative: bool,
}

impl ReferNode {
    pub fn center(&self) -> DVec3 {
        self.bbox.centre
    }
}

/// A snapshot of the map for queries.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReferScene {
    pub nodes: Vec<ReferNode>,
    /// The vocabulary's phrases and text embeddings (`names` is over these).
    pub phrases: Vec<String>,
    pub embeddings: Vec<Vec<f32>>,
    /// Per phrase, what one does with its objects (the vocabulary file's `functions`).
    pub functions: Vec<Vec<String>>,
    /// Newest first, with the map's depth rendered in each.
    pub keyframes: Vec<Keyframe>,
    pub depths: Vec<Vec<f32>>,
    /// Per keyframe, its sensor's depth where the node kept it (masks are cut by it).
    pub measured: Vec<Option<Arc<MeasuredDepth>>>,
    /// Per keyframe with `measured`, `depths` resampled to its sensor's resolution (where the
    /// sensor read nothing, an answer's splats are cut by it): once a snapshot, not an answer.
    pub measured_reference: Vec<Vec<f32>>,
    /// The camera's pictures of the instances (the evidence shows them where kept).
    pub observations: Observations,
    /// The scene graph over the same keyframes (every instance, structure included).
    pub graph: SceneGraph,
    /// Per keyframe, each pixel's instance (index into `map.instances`; `None`: nothing there):
    /// the whole map rendered with one label per instance, so the nearest surface wins.
    pub labels: Vec<Vec<Option<u32>>>,
    /// The map the snapshot was taken of: answers take their Gaussians from here, so an answer
    /// is consistent with the scores that chose it even when the live map moved on.
    pub map: Arc<SceneMap>,
}

impl ReferScene {
    /// Snapshot `map`, naming instances with `vocabulary` (none: instances are unnamed and no
    /// concept can be matched).
    pub fn build(map: SceneMap, vocabulary: Option<&Vocabulary>) -> Result<Self, GraphError> {
        let listed = query_list(&map, vocabulary, |i, box_like| i.fitted(box_like));
        Self::build_listed(map, vocabulary, listed)
    }

    /// The snapshot with `views`' sensor depth attached to the keyframes taken at the same
    /// instant (the others keep none).
    pub fn with_measured(mut self, views: &[Arc<MeasuredDepth>]) -> Self {
        self.measured = self
            .keyframes
            .iter()
            .map(|k| {
                views
                    .iter()
                    .find(|m| {
                        // Two cameras may share a stamp, never a pose.
                        m.keyframe.stamp_nanos == k.stamp_nanos
                            && m.keyframe.world_from_camera == k.world_from_camera
                    })
                    .cloned()
            })
            .collect();
        self.measured_reference = self
            .measured
            .iter()
            .enumerate()
            .map(
                |(k, m)| match (m, self.keyframes.get(k), self.depths.get(k)) {
                    (Some(m), Some(keyframe), Some(depth)) => {
                        resampled(depth, pixels(keyframe), pixels(&m.keyframe))
                    }
                    _ => Vec::new(),
                },
            )
            .collect();
        self
    }

    /// The snapshot with the camera's pictures of its instances.
    pub fn with_observations(mut self, observations: Observations) -> Self {
        self.observations = observations;
        self
    }

    /// As [`ReferScene::build`], with the map's object list already made (e.g. with the
    /// instance messages of the same map, so an answer's box is the one published).
    pub fn build_listed(
        map: SceneMap,
        vocabulary: Option<&Vocabulary>,
        mut listed: QueryList,
    ) -> Result<Self, GraphError> {
        let (graph, renders) = map.graph_with_renders(SNAPSHOT_VIEWS, SNAPSHOT_EDGE_DISTANCE_M)?;
        let (depths, labels): (Vec<Vec<f32>>, Vec<Vec<Option<u32>>>) = renders
            .into_iter()
            .map(|r| {
                // A pixel is an instance's where the map is opaque enough there (as masks are).
                let labels = r
                    .labels
                    .iter()
                    .zip(&r.alpha)
                    .map(|(l, a)| l.filter(|_| *a > MASK_ALPHA))
                    .collect();
                (r.depth, labels)
            })
            .unzip();
        let mut nodes = Vec::new();
        for (instance, node) in map.instances.iter().zip(&graph.nodes) {
            // What the object list leaves out (structure, small unsure pieces) is no candidate,
            // unless it is a tentative one.
            let Some((bbox, names, tentative)) = listed.remove(&instance.id) else {
                continue;
            };
            let best = names
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .map(|(i, _)| i);
            let label = match (vocabulary, best) {
                (Some(v), Some(i)) => v.phrases[i].clone(),
                _ => String::new(),
            };
            let (lo, hi) = box_bounds(&bbox);
            let n = instance.gaussians.len().max(1) as f32;
            let color = instance
                .gaussians
                .colors
                .iter()
                .fold(glam::Vec3::ZERO, |sum, c| sum + *c)
                / n;
            nodes.push(ReferNode {
                id: instance.id.clone(),
                names,
                label,
                bbox,
                lo,
                hi,
                color: color.clamp(glam::Vec3::ZERO, glam::Vec3::ONE).to_array(),
                visibility: node.views.iter().map(|v| v.visibility).fold(0.0, f32::max),
                confidence: instance.confidence,
                gaussians: instance.gaussians.len(),
                tentative,
            });
        }
        Ok(Self {
            nodes,
            phrases: vocabulary.map(|v| v.phrases.clone()).unwrap_or_default(),
            embeddings: vocabulary.map(|v| v.embeddings.clone()).unwrap_or_default(),
            functions: vocabulary
                .map(|v| {
                    v.phrases
                        .iter()
                        .map(|p| v.priors.functions(p).to_vec())
                        .collect()
                })
                .unwrap_or_default(),
            keyframes: map
                .keyframes
                .iter()
                .rev()
                .take(SNAPSHOT_VIEWS)
                .cloned()
                .collect(),
            measured: Vec::new(),
            measured_reference: Vec::new(),
            observations: Observations::default(),
            depths,
            graph,
            labels,
            map: Arc::new(map),
        })
    }

    pub fn node(&self, id: &str) -> Option<&ReferNode> {
        self.nodes.iter().find(|n| n.id == id)
    }

    /// The Gaussians of the snapshot's instance `id` (empty if it has none).
    pub fn gaussians(&self, id: &str) -> Gaussians {
        self.map
            .instances
            .iter()
            .find(|i| i.id == id)
            .map(|i| i.gaussians.clone())
            .unwrap_or_default()
    }
}

/// The object list as queries read it, by instance id: its published box, p(name) for every
/// phrase of the vocabulary, and whether it is a tentative candidate only (not published).
pub type QueryList = HashMap<String, (OrientedBox, Vec<f32>, bool)>;

/// `map`'s object list with its tentative candidates ([`object_list_with_tentative`]), boxes
/// fitted by `fit`.
pub fn query_list(
    map: &SceneMap,
    vocabulary: Option<&Vocabulary>,
    fit: impl FnMut(&crate::graph::Instance, bool) -> crate::graph::Fitted,
) -> QueryList {
    object_list_with_tentative(map, vocabulary, fit)
        .into_iter()
        .map(|l| (l.instance.id.clone(), (l.bbox, l.names, l.tentative)))
        .collect()
}

/// A keyframe's image size (columns, rows).
pub(super) fn pixels(keyframe: &Keyframe) -> (usize, usize) {
    (
        keyframe.camera.width as usize,
        keyframe.camera.height as usize,
    )
}

/// `image` (`from` = width, height) sampled at the nearest pixel into `to`'s size; empty when
/// `image` does not hold `from`'s pixels.
pub fn resampled(image: &[f32], from: (usize, usize), to: (usize, usize)) -> Vec<f32> {
    let ((fw, fh), (tw, th)) = (from, to);
    if fw == 0 || fh == 0 || image.len() != fw * fh {
        return Vec::new();
    }
    // Each column's and row's source, once: the image is read without a division a pixel.
    let columns: Vec<usize> = (0..tw).map(|x| (x * fw / tw.max(1)).min(fw - 1)).collect();
    (0..th)
        .flat_map(|y| {
            let row = &image[(y * fh / th.max(1)).min(fh - 1) * fw..][..fw];
            columns.iter().map(move |&x| row[x])
        })
        .collect()
}

/// Axis-aligned bounds of a gravity-aligned box turned by its yaw.
pub fn box_bounds(b: &OrientedBox) -> (DVec3, DVec3) {
    let (c, s) = (b.yaw.cos().abs(), b.yaw.sin().abs());
    let half = DVec3::new(
        (c * b.size.x + s * b.size.y) / 2.0,
        (s * b.size.x + c * b.size.y) / 2.0,
        b.size.z / 2.0,
    );
    (b.centre - half, b.centre + half)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_of_a_turned_box_contain_its_corners() {
        let b = OrientedBox {
            centre: DVec3::new(1.0, 2.0, 0.5),
            size: DVec3::new(2.0, 1.0, 1.0),
            yaw: std::f64::consts::FRAC_PI_2,
        };
        let (lo, hi) = box_bounds(&b);
        assert!((lo - DVec3::new(0.5, 1.0, 0.0)).length() < 1e-9, "{lo}");
        assert!((hi - DVec3::new(1.5, 3.0, 1.0)).length() < 1e-9, "{hi}");
        let degenerate = OrientedBox::from_bounds(DVec3::ONE, DVec3::ONE);
        let (lo, hi) = box_bounds(&degenerate);
        assert_eq!(lo, hi);
        assert!(lo.is_finite());
    }
}
