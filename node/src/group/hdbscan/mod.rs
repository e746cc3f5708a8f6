//! HDBSCAN (Campello et al. 2013; McInnes et al. 2017) for low-dimensional embeddings, with the
//! semantics of the Python `hdbscan` package: core distance = distance to the `min_samples`-th
//! nearest point counting the point itself, mutual reachability max(core_a, core_b, d(a, b)),
//! minimum spanning tree, single-linkage hierarchy, condensed tree with `min_cluster_size`,
//! excess-of-mass selection, noise labelled -1.
//!
//! Embeddings in one cell of a grid may be taken as one weighted point ([`hdbscan_gridded`], the
//! grouping's default). The fast path is the minimum spanning tree: Borůvka rounds over a
//! KD-tree, where each point looks for its nearest point of another component under mutual
//! reachability. Searches prune subtrees that lie entirely in the point's own component, subtrees
//! whose lower bound max(core_a, min core in the subtree, box distance) cannot beat the
//! component's best edge so far (shared between threads), and points whose own core distance
//! already exceeds it. The `hdbscan` crate builds the full mutual-reachability graph instead,
//! which is what made it 3–6× slower than Python here (issue 7).

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HdbscanError {
    #[error("points must be a whole number of {dims}-d rows, got {len} values")]
    Shape { len: usize, dims: usize },
    #[error("point {0} has a non-finite coordinate")]
    NonFinite(usize),
    #[error("min_cluster_size must be at least 2 and min_samples at least 1")]
    Parameters,
    #[error("the grid resolution must be finite and positive, got {0}")]
    Resolution(f64),
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
mod grid;
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
    let n = match check(points, dims, params)? {
        Checked::Points(n) => n,
        Checked::TooFew(noise) => return Ok(noise),
    };
    let data: Vec<f64> = points.iter().map(|&v| f64::from(v)).collect();
    // A single point is never a cluster's size alone (min_cluster_size ≥ 2): no leaf λ is used.
    Ok(cluster_weighted(
        &data,
        &vec![1; n],
        dims,
        params,
        f64::INFINITY,
    ))
}

/// [`hdbscan`] with points in one grid cell of side `resolution` taken as one point at their
/// mean, weighted by their count (in core distances, cluster sizes and stabilities). Far faster
/// on embeddings that crowd around their instances' centres, and the same up to that resolution:
/// the 18 windows of benchmark 100-104, their embeddings assigned to the clusters' centroids as
/// `group` does, agreed with the exact clustering's at ARI ≥ 0.996 (mean 1.000) at 0.005, in 12
/// against 40 ms on 2 threads.
pub fn hdbscan_gridded(
    points: &[f32],
    dims: usize,
    params: &HdbscanParams,
    resolution: f64,
) -> Result<Clustering, HdbscanError> {
    if !(resolution.is_finite() && resolution > 0.0) {
        return Err(HdbscanError::Resolution(resolution));
    }
    if let Checked::TooFew(noise) = check(points, dims, params)? {
        return Ok(noise);
    }
    let grid = grid::cells(points, dims, resolution);
    let by_cell = if grid.weights.len() == 1 {
        // One point, repeated: one cluster where a single cluster is allowed.
        let single = params.allow_single_cluster;
        Clustering {
            labels: vec![if single { 0 } else { -1 }],
            n_clusters: usize::from(single),
        }
    } else {
        cluster_weighted(&grid.means, &grid.weights, dims, params, 1.0 / resolution)
    };
    Ok(Clustering {
        labels: grid.of_point.iter().map(|&c| by_cell.labels[c]).collect(),
        n_clusters: by_cell.n_clusters,
    })
}

/// What the checks of shape, parameters and values found.
enum Checked {
    /// This many points, enough for a cluster.
    Points(usize),
    /// Too few points for any cluster: all noise.
    TooFew(Clustering),
}

fn check(points: &[f32], dims: usize, params: &HdbscanParams) -> Result<Checked, HdbscanError> {
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
    Ok(if n < params.min_cluster_size.max(2) {
        Checked::TooFew(Clustering {
            labels: vec![-1; n],
            n_clusters: 0,
        })
    } else {
        Checked::Points(n)
    })
}

/// HDBSCAN over at least two points `data` (row-major), point i standing for `weights[i]`
/// embeddings: its core distance is the distance at which its nearest points' weights (its own
/// included) reach `min_samples`; one heavy enough to be a cluster alone lasts to `leaf_lambda`
/// ([`condense`]).
fn cluster_weighted(
    data: &[f64],
    weights: &[usize],
    dims: usize,
    params: &HdbscanParams,
    leaf_lambda: f64,
) -> Clustering {
    let n = weights.len();
    let tree = KdTree::build(data, dims);
    let weight_in_tree: Vec<usize> = tree.order.iter().map(|&i| weights[i]).collect();
    let neighbors = tree.knn_all(params.min_samples.min(n));
    let core: Vec<f64> = neighbors
        .iter()
        .map(|nn| {
            let mut total = 0;
            nn.iter()
                .find(|&&(_, j)| {
                    total += weight_in_tree[j];
                    total >= params.min_samples
                })
                .or(nn.last())
                .map_or(0.0, |x| x.0)
        })
        .collect();
    let edges: Vec<(usize, usize, f64)> = mutual_reachability_mst(&tree, &core, &neighbors)
        .into_iter()
        .map(|(a, b, d2)| (a, b, d2.sqrt()))
        .collect();
    let merges = single_linkage(&weight_in_tree, edges);
    let rows = condense(
        &weight_in_tree,
        &merges,
        params.min_cluster_size,
        leaf_lambda,
    );
    let in_tree_order = select_and_label(n, &rows, params.allow_single_cluster);
    let mut labels = vec![-1; n];
    for (i, &original) in tree.order.iter().enumerate() {
        labels[original] = in_tree_order.labels[i];
    }
    Clustering {
        labels,
        n_clusters: in_tree_order.n_clusters,
    }
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
