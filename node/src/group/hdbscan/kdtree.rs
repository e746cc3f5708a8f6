//! The KD-tree the fast paths search: built once over the points in tree order, with parallel
//! k-nearest-neighbour queries for the core distances.

use rayon::prelude::*;

const LEAF_SIZE: usize = 32;

/// A point's nearest neighbours: (squared distance, tree-order index), nearest first.
pub(super) type Neighbors = Vec<(f64, usize)>;

/// Push two children so that the nearer one is popped (searched) first.
pub(super) fn push_nearer_last(stack: &mut Vec<(usize, f64)>, a: (usize, f64), b: (usize, f64)) {
    if a.1 <= b.1 {
        stack.push(b);
        stack.push(a);
    } else {
        stack.push(a);
        stack.push(b);
    }
}

/// Insert `(d, j)` into the ascending list of the `k` best if it beats the worst.
pub(super) fn insert_best(best: &mut Neighbors, k: usize, d: f64, j: usize) {
    if best.len() < k || d < best[k - 1].0 {
        let at = best.partition_point(|x| x.0 <= d);
        best.insert(at, (d, j));
        best.truncate(k);
    }
}

/// Keep candidate edge `(d, b)` if it is within the component's bound and beats `best` (ties go
/// to the smaller index, so the outcome does not depend on search order).
pub(super) fn consider(best: &mut Option<(f64, usize)>, d: f64, b: usize, bound: f64) {
    let better = d <= bound
        && match *best {
            None => true,
            Some((bd, bb)) => d < bd || (d == bd && b < bb),
        };
    if better {
        *best = Some((d, b));
    }
}

/// Squared distance between the boxes [a_lo, a_hi] and [b_lo, b_hi] (a point is a box with
/// a_lo = a_hi). The embedding width (8) gets a fixed-size path the compiler vectorises: the
/// searches spend most of their time here.
fn gap2(a_lo: &[f64], a_hi: &[f64], b_lo: &[f64], b_hi: &[f64]) -> f64 {
    #[inline(always)]
    fn one(a_lo: f64, a_hi: f64, b_lo: f64, b_hi: f64) -> f64 {
        let gap = (b_lo - a_hi).max(a_lo - b_hi).max(0.0);
        gap * gap
    }
    if let (Ok(al), Ok(ah), Ok(bl), Ok(bh)) = (
        <&[f64; 8]>::try_from(a_lo),
        <&[f64; 8]>::try_from(a_hi),
        <&[f64; 8]>::try_from(b_lo),
        <&[f64; 8]>::try_from(b_hi),
    ) {
        let mut partial = [0.0f64; 4];
        for i in 0..4 {
            partial[i] =
                one(al[i], ah[i], bl[i], bh[i]) + one(al[i + 4], ah[i + 4], bl[i + 4], bh[i + 4]);
        }
        return (partial[0] + partial[1]) + (partial[2] + partial[3]);
    }
    (0..a_lo.len())
        .map(|i| one(a_lo[i], a_hi[i], b_lo[i], b_hi[i]))
        .sum()
}

/// A KD-tree over points stored in tree order.
pub(super) struct KdTree {
    pub(super) dims: usize,
    /// Points in tree order, row-major.
    pub(super) points: Vec<f64>,
    /// Tree order → input index.
    pub(super) order: Vec<usize>,
    pub(super) nodes: Vec<KdNode>,
    /// Per node: bounding box (lo, hi), `dims` values each.
    pub(super) lo: Vec<f64>,
    pub(super) hi: Vec<f64>,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct KdNode {
    pub(super) start: usize,
    pub(super) end: usize,
    /// Children, or `usize::MAX` for a leaf.
    pub(super) left: usize,
    pub(super) right: usize,
}

impl KdTree {
    pub(super) fn build(points: &[f64], dims: usize) -> Self {
        let n = points.len() / dims;
        let mut tree = Self {
            dims,
            points: Vec::new(),
            order: (0..n).collect(),
            nodes: Vec::new(),
            lo: Vec::new(),
            hi: Vec::new(),
        };
        if n > 0 {
            tree.split(points, 0, n);
        }
        let mut sorted = Vec::with_capacity(points.len());
        for &i in &tree.order {
            sorted.extend_from_slice(&points[i * dims..(i + 1) * dims]);
        }
        tree.points = sorted;
        tree
    }

    /// Build the node for `order[start..end]` and return its index.
    pub(super) fn split(&mut self, points: &[f64], start: usize, end: usize) -> usize {
        let dims = self.dims;
        let id = self.nodes.len();
        self.nodes.push(KdNode {
            start,
            end,
            left: usize::MAX,
            right: usize::MAX,
        });
        let (mut lo, mut hi) = (vec![f64::INFINITY; dims], vec![f64::NEG_INFINITY; dims]);
        for &i in &self.order[start..end] {
            for d in 0..dims {
                let v = points[i * dims + d];
                lo[d] = lo[d].min(v);
                hi[d] = hi[d].max(v);
            }
        }
        let widest = (0..dims)
            .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
            .unwrap_or(0);
        let spread = hi[widest] - lo[widest];
        self.lo.extend_from_slice(&lo);
        self.hi.extend_from_slice(&hi);
        if end - start > LEAF_SIZE && spread > 0.0 {
            let mid = start + (end - start) / 2;
            self.order[start..end].select_nth_unstable_by(mid - start, |&a, &b| {
                points[a * dims + widest].total_cmp(&points[b * dims + widest])
            });
            let left = self.split(points, start, mid);
            let right = self.split(points, mid, end);
            self.nodes[id].left = left;
            self.nodes[id].right = right;
        }
        id
    }

    pub(super) fn point(&self, i: usize) -> &[f64] {
        &self.points[i * self.dims..(i + 1) * self.dims]
    }

    /// Squared distances throughout: ordering is all the searches need, and it saves a root per
    /// candidate.
    pub(super) fn distance2(&self, a: &[f64], b: usize) -> f64 {
        let b = self.point(b);
        // The embedding width (d_e = 8) gets a fixed-size path the compiler unrolls into SIMD
        // with four independent partial sums.
        if let (Ok(a), Ok(b)) = (<&[f64; 8]>::try_from(a), <&[f64; 8]>::try_from(b)) {
            let mut partial = [0.0f64; 4];
            for i in 0..4 {
                let (d0, d1) = (a[i] - b[i], a[i + 4] - b[i + 4]);
                partial[i] = d0 * d0 + d1 * d1;
            }
            return (partial[0] + partial[1]) + (partial[2] + partial[3]);
        }
        a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>()
    }

    /// Squared distance from `p` to the node's box.
    pub(super) fn box_distance2(&self, p: &[f64], node: usize) -> f64 {
        let d = self.dims;
        gap2(
            p,
            p,
            &self.lo[node * d..(node + 1) * d],
            &self.hi[node * d..(node + 1) * d],
        )
    }

    /// The k nearest points of every point (tree order, counting itself) as (squared distance,
    /// index), nearest first: one descent per point, pruned by its own k-th distance. (One
    /// traversal per leaf, pruned by the worst bound among the leaf's points, took a quarter more
    /// time on window embeddings, same neighbours: a loose point widened its leaf-mates' search.)
    pub(super) fn knn_all(&self, k: usize) -> Vec<Neighbors> {
        let n = self.points.len() / self.dims.max(1);
        (0..n).into_par_iter().map(|i| self.knn(i, k)).collect()
    }

    /// The k nearest points of point `i` (tree order, counting itself) as (squared distance,
    /// index), nearest first.
    pub(super) fn knn(&self, i: usize, k: usize) -> Vec<(f64, usize)> {
        let p = self.point(i);
        let mut best: Vec<(f64, usize)> = Vec::with_capacity(k + 1);
        let mut stack = vec![(0usize, 0.0f64)];
        while let Some((node, box_distance)) = stack.pop() {
            if best.len() == k && box_distance >= best[k - 1].0 {
                continue;
            }
            let n = self.nodes[node];
            if n.left == usize::MAX {
                for j in n.start..n.end {
                    insert_best(&mut best, k, self.distance2(p, j), j);
                }
            } else {
                let (a, b) = (n.left, n.right);
                push_nearer_last(
                    &mut stack,
                    (a, self.box_distance2(p, a)),
                    (b, self.box_distance2(p, b)),
                );
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Squared box-to-box distance, one dimension after the other.
    fn plain_gap2(a_lo: &[f64], a_hi: &[f64], b_lo: &[f64], b_hi: &[f64]) -> f64 {
        let mut sum = 0.0;
        for i in 0..a_lo.len() {
            let gap = if b_lo[i] > a_hi[i] {
                b_lo[i] - a_hi[i]
            } else if a_lo[i] > b_hi[i] {
                a_lo[i] - b_hi[i]
            } else {
                0.0
            };
            sum += gap * gap;
        }
        sum
    }

    #[test]
    fn box_distances_match_the_plain_sum_in_the_fast_and_the_general_width() {
        let (values, _) = crate::group::blobs::blobs(400, 1, 3, 2.0, 5);
        for dims in [8usize, 3] {
            for case in values.chunks(4 * dims).filter(|c| c.len() == 4 * dims) {
                let v: Vec<f64> = case.iter().map(|&x| f64::from(x)).collect();
                let (a, b) = (&v[..2 * dims], &v[2 * dims..]);
                // Boxes from two corners each (lo ≤ hi per axis).
                let lo = |c: &[f64]| (0..dims).map(|i| c[i].min(c[dims + i])).collect::<Vec<_>>();
                let hi = |c: &[f64]| (0..dims).map(|i| c[i].max(c[dims + i])).collect::<Vec<_>>();
                let (al, ah, bl, bh) = (lo(a), hi(a), lo(b), hi(b));
                let fast = gap2(&al, &ah, &bl, &bh);
                let plain = plain_gap2(&al, &ah, &bl, &bh);
                assert!(
                    (fast - plain).abs() <= 1e-12 * plain.max(1.0),
                    "{fast} {plain}"
                );
                // A point inside its own box is at distance 0; symmetric between boxes.
                assert_eq!(gap2(&al, &al, &al, &ah), 0.0);
                assert_eq!(gap2(&al, &ah, &bl, &bh), gap2(&bl, &bh, &al, &ah));
            }
        }
    }
}
