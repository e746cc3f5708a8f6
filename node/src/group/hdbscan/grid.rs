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
/// order of their grid coordinates (so the result does not depend on the input's order); each
/// cell's points summed in input order. Cells are found by hashing and only the occupied cells
/// sorted: sorting every point by its cell was a third of the grouping stage's own time.
pub(super) fn cells(points: &[f32], dims: usize, cell: f64) -> Cells {
    let n = points.len() / dims.max(1);
    let keys: Vec<i64> = points[..n * dims]
        .iter()
        .map(|&v| (f64::from(v) / cell).floor() as i64)
        .collect();
    let key = |i: usize| &keys[i * dims..(i + 1) * dims];
    // Cells in the order their first point comes, then sorted by their coordinates.
    let mut found: rustc_hash::FxHashMap<&[i64], usize> = rustc_hash::FxHashMap::default();
    let mut first_seen_of_point = Vec::with_capacity(n);
    let mut sums: Vec<f64> = Vec::new();
    let mut counts: Vec<usize> = Vec::new();
    for i in 0..n {
        let next = counts.len();
        let c = *found.entry(key(i)).or_insert(next);
        if c == next {
            counts.push(0);
            sums.extend(std::iter::repeat_n(0.0, dims));
        }
        counts[c] += 1;
        for (sum, &v) in sums[c * dims..(c + 1) * dims]
            .iter_mut()
            .zip(&points[i * dims..(i + 1) * dims])
        {
            *sum += f64::from(v);
        }
        first_seen_of_point.push(c);
    }
    let mut by_coordinates: Vec<(&[i64], usize)> = found.into_iter().collect();
    by_coordinates.sort_unstable();
    let mut rank = vec![0usize; counts.len()];
    let mut means = Vec::with_capacity(sums.len());
    let mut weights = Vec::with_capacity(counts.len());
    for (r, &(_, c)) in by_coordinates.iter().enumerate() {
        rank[c] = r;
        let w = counts[c];
        weights.push(w);
        means.extend(sums[c * dims..(c + 1) * dims].iter().map(|v| v / w as f64));
    }
    Cells {
        means,
        weights,
        of_point: first_seen_of_point.into_iter().map(|c| rank[c]).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The cells by sorting every point by its cell, then its index: what [`cells`] must equal.
    fn cells_by_sorting_points(points: &[f32], dims: usize, cell: f64) -> Cells {
        let n = points.len() / dims;
        let keys: Vec<i64> = points
            .iter()
            .map(|&v| (f64::from(v) / cell).floor() as i64)
            .collect();
        let key = |i: usize| &keys[i * dims..(i + 1) * dims];
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| key(a).cmp(key(b)).then(a.cmp(&b)));
        let (mut means, mut weights, mut of_point) = (Vec::new(), Vec::new(), vec![0; n]);
        for (k, &i) in order.iter().enumerate() {
            if k == 0 || key(order[k - 1]) != key(i) {
                weights.push(0);
                means.extend(std::iter::repeat_n(0.0, dims));
            }
            let c = weights.len() - 1;
            weights[c] += 1;
            for (sum, &v) in means[c * dims..]
                .iter_mut()
                .zip(&points[i * dims..(i + 1) * dims])
            {
                *sum += f64::from(v);
            }
            of_point[i] = c;
        }
        for (row, &w) in means.chunks_mut(dims).zip(&weights) {
            row.iter_mut().for_each(|v| *v /= w as f64);
        }
        Cells {
            means,
            weights,
            of_point,
        }
    }

    #[test]
    fn cells_found_by_hashing_equal_cells_found_by_sorting_every_point() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for (n, dims, spread) in [(2000, 8, 0.02f32), (500, 3, 1.0), (1, 8, 0.1), (0, 8, 0.1)] {
            // Clumps around a few centres, as trained embeddings are: many points share a cell.
            let centres: Vec<f32> = (0..5 * dims).map(|_| rng.random_range(-1.0..1.0)).collect();
            let points: Vec<f32> = (0..n * dims)
                .map(|k| {
                    centres[(k / dims % 5) * dims + k % dims] + rng.random_range(-spread..spread)
                })
                .collect();
            assert_eq!(
                cells(&points, dims, 0.005),
                cells_by_sorting_points(&points, dims, 0.005),
                "{n} points of {dims} dims"
            );
        }
    }

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
