//! HDBSCAN (Campello et al. 2013; McInnes et al. 2017) for low-dimensional embeddings, with the
//! semantics of the Python `hdbscan` package: core distance = distance to the `min_samples`-th
//! nearest point counting the point itself, mutual reachability max(core_a, core_b, d(a, b)),
//! minimum spanning tree, single-linkage hierarchy, condensed tree with `min_cluster_size`,
//! excess-of-mass selection, noise labelled -1.
//!
//! The fast path is the minimum spanning tree: Borůvka rounds over a KD-tree, where each point
//! looks for its nearest point of another component under mutual reachability. Searches prune
//! subtrees that lie entirely in the point's own component, subtrees whose lower bound
//! max(core_a, min core in the subtree, box distance) cannot beat the component's best edge so far
//! (shared between threads), and points whose own core distance already exceeds it. The `hdbscan`
//! crate builds the full mutual-reachability graph instead, which is what made it 3–6× slower than
//! Python here (issue 7).

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HdbscanError {
    #[error("points must be a whole number of {dims}-d rows, got {len} values")]
    Shape { len: usize, dims: usize },
    #[error("point {0} has a non-finite coordinate")]
    NonFinite(usize),
    #[error("min_cluster_size must be at least 2 and min_samples at least 1")]
    Parameters,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HdbscanParams {
    pub min_cluster_size: usize,
    /// Neighbours (counting the point itself) that define a point's core distance.
    pub min_samples: usize,
    /// Let the root be selected, so data with one cluster gets one cluster rather than noise.
    pub allow_single_cluster: bool,
}

impl Default for HdbscanParams {
    fn default() -> Self {
        Self {
            min_cluster_size: 60,
            min_samples: 10,
            allow_single_cluster: false,
        }
    }
}

mod condensed;
mod kdtree;
mod mst;

pub use condensed::Clustering;
use condensed::{condense, select_and_label, single_linkage};
use kdtree::KdTree;
use mst::mutual_reachability_mst;

/// Cluster `points` (row-major, `dims` values per point).
pub fn hdbscan(
    points: &[f32],
    dims: usize,
    params: &HdbscanParams,
) -> Result<Clustering, HdbscanError> {
    if dims == 0 || points.len() % dims != 0 {
        return Err(HdbscanError::Shape {
            len: points.len(),
            dims,
        });
    }
    if params.min_cluster_size < 2 || params.min_samples < 1 {
        return Err(HdbscanError::Parameters);
    }
    let n = points.len() / dims;
    if let Some(bad) = (0..n).find(|&i| {
        points[i * dims..(i + 1) * dims]
            .iter()
            .any(|v| !v.is_finite())
    }) {
        return Err(HdbscanError::NonFinite(bad));
    }
    if n < params.min_cluster_size.max(2) {
        // Too few points for any cluster: all noise (a single cluster if allowed and enough).
        return Ok(Clustering {
            labels: vec![-1; n],
            n_clusters: 0,
        });
    }
    let data: Vec<f64> = points.iter().map(|&v| f64::from(v)).collect();
    let tree = KdTree::build(&data, dims);
    let k = params.min_samples.min(n);
    let neighbors = tree.knn_all(k);
    let core: Vec<f64> = neighbors
        .iter()
        .map(|nn| nn.last().map_or(0.0, |x| x.0))
        .collect();
    let edges: Vec<(usize, usize, f64)> = mutual_reachability_mst(&tree, &core, &neighbors)
        .into_iter()
        .map(|(a, b, d2)| (a, b, d2.sqrt()))
        .collect();
    let merges = single_linkage(n, edges);
    let rows = condense(n, &merges, params.min_cluster_size);
    let in_tree_order = select_and_label(n, &rows, params.allow_single_cluster);
    let mut labels = vec![-1; n];
    for (i, &original) in tree.order.iter().enumerate() {
        labels[original] = in_tree_order.labels[i];
    }
    Ok(Clustering {
        labels,
        n_clusters: in_tree_order.n_clusters,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn knn_of_every_point_equals_brute_force() {
        let (points, _) = crate::group::blobs::blobs(3000, 8, 5, 1.0, 9);
        let data: Vec<f64> = points.iter().map(|&v| f64::from(v)).collect();
        let tree = KdTree::build(&data, 8);
        let all = tree.knn_all(10);
        for i in (0..3000).step_by(7) {
            let p = tree.point(i);
            let mut brute: Vec<f64> = (0..3000).map(|j| tree.distance2(p, j)).collect();
            brute.sort_by(f64::total_cmp);
            let found: Vec<f64> = all[i].iter().map(|x| x.0).collect();
            assert_eq!(found, brute[..10], "point {i}");
            assert_eq!(all[i][0], (0.0, i), "a point is its own nearest");
        }
    }
}
