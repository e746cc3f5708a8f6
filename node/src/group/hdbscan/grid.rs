//! Embeddings closer than a resolution as one weighted point: the window's embeddings are pulled
//! tight around their instance's centre in training, so 70% of a window's 16,384 sampled
//! embeddings (43-86% by window) share a grid cell of side 0.005 with another, 5,100 occupied
//! cells on average (benchmark 100-104, 18 windows), and the k-NN and spanning-tree searches
//! spent most of their time among such near-duplicates.

/// The occupied grid cells of a point set: each cell's mean, its count, and each point's cell.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Cells {
    /// Mean of each cell's points, row-major (`dims` values per cell), in f64 as the tree wants.
    pub(super) means: Vec<f64>,
    /// Points per cell.
    pub(super) weights: Vec<usize>,
    /// Per input point: its cell.
    pub(super) of_point: Vec<usize>,
}

/// The cells of side `cell` that `points` (row-major, `dims` per row, finite) occupy, in the
/// order of their grid coordinates (so the result does not depend on the input's order).
pub(super) fn cells(points: &[f32], dims: usize, cell: f64) -> Cells {
    let n = points.len() / dims.max(1);
    let keys: Vec<i64> = points
        .iter()
        .map(|&v| (f64::from(v) / cell).floor() as i64)
        .collect();
    let key = |i: usize| &keys[i * dims..(i + 1) * dims];
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_unstable_by(|&a, &b| key(a).cmp(key(b)).then(a.cmp(&b)));
    let mut means: Vec<f64> = Vec::new();
    let mut weights: Vec<usize> = Vec::new();
    let mut of_point = vec![0usize; n];
    let mut previous: Option<usize> = None;
    for &i in &order {
        if previous.is_none_or(|p| key(p) != key(i)) {
            weights.push(0);
            means.extend(std::iter::repeat_n(0.0, dims));
        }
        previous = Some(i);
        let c = weights.len() - 1;
        weights[c] += 1;
        for (sum, &v) in means[c * dims..(c + 1) * dims]
            .iter_mut()
            .zip(&points[i * dims..(i + 1) * dims])
        {
            *sum += f64::from(v);
        }
        of_point[i] = c;
    }
    for (row, &w) in means.chunks_mut(dims.max(1)).zip(&weights) {
        row.iter_mut().for_each(|v| *v /= w as f64);
    }
    Cells {
        means,
        weights,
        of_point,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_within_a_cell_become_one_weighted_mean_whatever_their_order() {
        // Two points in one cell of side 0.1, one alone; negative coordinates floor downwards.
        let points = [0.01f32, -0.02, 0.05, -0.08, 0.5, 0.5];
        let grid = cells(&points, 2, 0.1);
        assert_eq!(grid.weights.len(), 2);
        let first = grid.of_point[0];
        assert_eq!(grid.of_point[1], first);
        assert_ne!(grid.of_point[2], first);
        assert_eq!(grid.weights[first], 2);
        let mean = &grid.means[first * 2..first * 2 + 2];
        assert!((mean[0] - 0.03).abs() < 1e-7 && (mean[1] + 0.05).abs() < 1e-7);
        let reversed = [0.5f32, 0.5, 0.05, -0.08, 0.01, -0.02];
        let again = cells(&reversed, 2, 0.1);
        assert_eq!(again.weights, grid.weights);
        assert_eq!(again.means, grid.means);
    }
}
