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

use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

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

/// Labels (`-1` noise, clusters `0..n_clusters`) in input order.
#[derive(Debug, Clone, PartialEq)]
pub struct Clustering {
    pub labels: Vec<i32>,
    pub n_clusters: usize,
}

/// Distances below this are treated as this, so λ = 1/d stays finite for duplicate points.
const MIN_DISTANCE: f64 = 1e-12;

const LEAF_SIZE: usize = 32;

/// A point's nearest neighbours: (squared distance, tree-order index), nearest first.
type Neighbors = Vec<(f64, usize)>;

/// Push two children so that the nearer one is popped (searched) first.
fn push_nearer_last(stack: &mut Vec<(usize, f64)>, a: (usize, f64), b: (usize, f64)) {
    if a.1 <= b.1 {
        stack.push(b);
        stack.push(a);
    } else {
        stack.push(a);
        stack.push(b);
    }
}

/// Insert `(d, j)` into the ascending list of the `k` best if it beats the worst.
fn insert_best(best: &mut Neighbors, k: usize, d: f64, j: usize) {
    if best.len() < k || d < best[k - 1].0 {
        let at = best.partition_point(|x| x.0 <= d);
        best.insert(at, (d, j));
        best.truncate(k);
    }
}

/// Keep candidate edge `(d, b)` if it is within the component's bound and beats `best` (ties go
/// to the smaller index, so the outcome does not depend on search order).
fn consider(best: &mut Option<(f64, usize)>, d: f64, b: usize, bound: f64) {
    let better = d <= bound
        && match *best {
            None => true,
            Some((bd, bb)) => d < bd || (d == bd && b < bb),
        };
    if better {
        *best = Some((d, b));
    }
}

/// A KD-tree over points stored in tree order.
struct KdTree {
    dims: usize,
    /// Points in tree order, row-major.
    points: Vec<f64>,
    /// Tree order → input index.
    order: Vec<usize>,
    nodes: Vec<KdNode>,
    /// Per node: bounding box (lo, hi), `dims` values each.
    lo: Vec<f64>,
    hi: Vec<f64>,
}

#[derive(Debug, Clone, Copy)]
struct KdNode {
    start: usize,
    end: usize,
    /// Children, or `usize::MAX` for a leaf.
    left: usize,
    right: usize,
}

impl KdTree {
    fn build(points: &[f64], dims: usize) -> Self {
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
    fn split(&mut self, points: &[f64], start: usize, end: usize) -> usize {
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

    fn point(&self, i: usize) -> &[f64] {
        &self.points[i * self.dims..(i + 1) * self.dims]
    }

    /// Squared distances throughout: ordering is all the searches need, and it saves a root per
    /// candidate.
    fn distance2(&self, a: &[f64], b: usize) -> f64 {
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
    fn box_distance2(&self, p: &[f64], node: usize) -> f64 {
        let (lo, hi) = (
            &self.lo[node * self.dims..(node + 1) * self.dims],
            &self.hi[node * self.dims..(node + 1) * self.dims],
        );
        p.iter()
            .enumerate()
            .map(|(d, &v)| {
                let gap = (lo[d] - v).max(v - hi[d]).max(0.0);
                gap * gap
            })
            .sum::<f64>()
    }

    /// Squared distance between two nodes' boxes.
    fn box_to_box2(&self, a: usize, b: usize) -> f64 {
        let d = self.dims;
        (0..d)
            .map(|i| {
                let gap = (self.lo[b * d + i] - self.hi[a * d + i])
                    .max(self.lo[a * d + i] - self.hi[b * d + i])
                    .max(0.0);
                gap * gap
            })
            .sum()
    }

    /// The k nearest points of every point (tree order, counting itself) as (squared distance,
    /// index), nearest first. Queries go leaf by leaf: the points of one leaf share a single
    /// traversal, pruned by box-to-box distance against the worst of their current bounds.
    fn knn_all(&self, k: usize) -> Vec<Vec<(f64, usize)>> {
        let leaves: Vec<usize> = (0..self.nodes.len())
            .filter(|&i| self.nodes[i].left == usize::MAX)
            .collect();
        let per_leaf: Vec<(usize, Vec<Neighbors>)> = leaves
            .par_iter()
            .map(|&leaf| {
                let q = self.nodes[leaf];
                let mut best: Vec<Vec<(f64, usize)>> = (q.start..q.end)
                    .map(|_| Vec::with_capacity(k + 1))
                    .collect();
                let bound = |b: &Vec<(f64, usize)>| {
                    if b.len() == k {
                        b[k - 1].0
                    } else {
                        f64::INFINITY
                    }
                };
                let mut worst = f64::INFINITY;
                let mut stack = vec![(0usize, 0.0f64)];
                while let Some((node, gap)) = stack.pop() {
                    if gap >= worst {
                        continue;
                    }
                    let n = self.nodes[node];
                    if n.left == usize::MAX {
                        for (slot, i) in (q.start..q.end).enumerate() {
                            let p = self.point(i);
                            let b = &mut best[slot];
                            if self.box_distance2(p, node) >= bound(b) {
                                continue;
                            }
                            for j in n.start..n.end {
                                insert_best(b, k, self.distance2(p, j), j);
                            }
                        }
                        worst = best.iter().map(bound).fold(0.0, f64::max);
                    } else {
                        let (l, r) = (n.left, n.right);
                        push_nearer_last(
                            &mut stack,
                            (l, self.box_to_box2(leaf, l)),
                            (r, self.box_to_box2(leaf, r)),
                        );
                    }
                }
                (q.start, best)
            })
            .collect();
        let mut out = vec![Vec::new(); self.points.len() / self.dims.max(1)];
        for (start, best) in per_leaf {
            for (slot, b) in best.into_iter().enumerate() {
                out[start + slot] = b;
            }
        }
        out
    }

    /// The k nearest points of point `i` (tree order, counting itself) as (squared distance,
    /// index), nearest first.
    #[cfg(test)]
    fn knn(&self, i: usize, k: usize) -> Vec<(f64, usize)> {
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

fn find(parent: &mut [usize], mut x: usize) -> usize {
    while parent[x] != x {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    x
}

/// Minimum spanning tree of the mutual-reachability graph (Borůvka over the KD-tree), as
/// (a, b, weight) in tree order. `core` holds squared core distances and `neighbors` each point's
/// k nearest (squared distance, index): they seed every search with a candidate, and settle it
/// outright when that candidate reaches the point's own core distance, the lowest any edge from
/// it can have.
fn mutual_reachability_mst(
    tree: &KdTree,
    core: &[f64],
    neighbors: &[Vec<(f64, usize)>],
) -> Vec<(usize, usize, f64)> {
    let n = core.len();
    let nodes = tree.nodes.len();
    // Smallest core distance under each node (static).
    let mut min_core = vec![f64::INFINITY; nodes];
    for node in (0..nodes).rev() {
        let k = tree.nodes[node];
        min_core[node] = if k.left == usize::MAX {
            core[k.start..k.end]
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min)
        } else {
            min_core[k.left].min(min_core[k.right])
        };
    }
    let mut parent: Vec<usize> = (0..n).collect();
    let mut edges = Vec::with_capacity(n.saturating_sub(1));
    let mut components = n;
    while components > 1 {
        let component: Vec<usize> = (0..n).map(|i| find(&mut parent, i)).collect();
        // The component of every node whose points all share one, else usize::MAX.
        let mut node_component = vec![usize::MAX; nodes];
        for node in (0..nodes).rev() {
            let k = tree.nodes[node];
            node_component[node] = if k.left == usize::MAX {
                let c = component[k.start];
                if component[k.start..k.end].iter().all(|&x| x == c) {
                    c
                } else {
                    usize::MAX
                }
            } else if node_component[k.left] == node_component[k.right] {
                node_component[k.left]
            } else {
                usize::MAX
            };
        }
        let best_of_component: Vec<AtomicU64> = (0..n)
            .map(|_| AtomicU64::new(f64::INFINITY.to_bits()))
            .collect();
        let candidates: Vec<Option<(f64, usize, usize)>> = (0..n)
            .into_par_iter()
            .map(|a| {
                let own = component[a];
                let shared = &best_of_component[own];
                let bound = || f64::from_bits(shared.load(Ordering::Relaxed));
                // Pruning is strict (`>`) everywhere: every point whose best edge ties the
                // component's minimum still reports it, so the chosen edge does not depend on
                // thread timing and the clustering is deterministic.
                if core[a] > bound() {
                    return None;
                }
                let p = tree.point(a);
                let mut best: Option<(f64, usize)> = None;
                for &(d, b) in &neighbors[a] {
                    if component[b] == own {
                        continue;
                    }
                    consider(&mut best, d.max(core[a]).max(core[b]), b, bound());
                }
                if best.is_some_and(|(d, _)| d <= core[a]) {
                    return best.map(|(d, b)| (d, a, b));
                }
                // (node, squared distance from p to its box), nearer children popped first.
                let mut stack = vec![(0usize, tree.box_distance2(p, 0))];
                while let Some((node, box_distance)) = stack.pop() {
                    if node_component[node] == own {
                        continue;
                    }
                    let limit = best.map_or(f64::INFINITY, |b| b.0).min(bound());
                    let lower = box_distance.max(core[a]).max(min_core[node]);
                    if lower > limit {
                        continue;
                    }
                    let k = tree.nodes[node];
                    if k.left == usize::MAX {
                        for b in k.start..k.end {
                            if component[b] == own {
                                continue;
                            }
                            let d = tree.distance2(p, b).max(core[a]).max(core[b]);
                            consider(&mut best, d, b, bound());
                        }
                        if let Some((d, _)) = best {
                            // Lower the component's shared bound.
                            let mut current = shared.load(Ordering::Relaxed);
                            while d < f64::from_bits(current) {
                                match shared.compare_exchange_weak(
                                    current,
                                    d.to_bits(),
                                    Ordering::Relaxed,
                                    Ordering::Relaxed,
                                ) {
                                    Ok(_) => break,
                                    Err(now) => current = now,
                                }
                            }
                        }
                    } else {
                        let (l, r) = (k.left, k.right);
                        push_nearer_last(
                            &mut stack,
                            (l, tree.box_distance2(p, l)),
                            (r, tree.box_distance2(p, r)),
                        );
                    }
                }
                best.map(|(d, b)| (d, a, b))
            })
            .collect();
        // Each component's cheapest edge, ties broken by index so the result is deterministic.
        let mut chosen: Vec<Option<(f64, usize, usize)>> = vec![None; n];
        for (d, a, b) in candidates.into_iter().flatten() {
            let key = (d, a.min(b), a.max(b));
            let slot = &mut chosen[component[a]];
            let replace = match slot {
                None => true,
                Some(current) => {
                    key.0 < current.0
                        || (key.0 == current.0 && (key.1, key.2) < (current.1, current.2))
                }
            };
            if replace {
                *slot = Some(key);
            }
        }
        let before = components;
        for (d, a, b) in chosen.into_iter().flatten() {
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            if ra != rb {
                parent[ra.max(rb)] = ra.min(rb);
                edges.push((a, b, d));
                components -= 1;
            }
        }
        if components == before {
            // Cannot happen with finite data; never loop forever.
            break;
        }
    }
    edges
}

/// One row of the condensed tree: `child` (a point < n, or a cluster ≥ n) leaves `parent` at
/// `lambda` = 1 / distance with `size` points.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CondensedRow {
    parent: usize,
    child: usize,
    lambda: f64,
    size: usize,
}

/// Single-linkage merges (left, right, distance, size) from MST edges; node ids ≥ n are merges.
fn single_linkage(
    n: usize,
    mut edges: Vec<(usize, usize, f64)>,
) -> Vec<(usize, usize, f64, usize)> {
    edges.sort_by(|x, y| x.2.total_cmp(&y.2).then((x.0, x.1).cmp(&(y.0, y.1))));
    let mut parent: Vec<usize> = (0..2 * n).collect();
    let mut size = vec![1usize; 2 * n];
    let mut merges = Vec::with_capacity(n.saturating_sub(1));
    for (a, b, d) in edges {
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        let id = n + merges.len();
        parent[ra] = id;
        parent[rb] = id;
        size[id] = size[ra] + size[rb];
        merges.push((ra, rb, d, size[id]));
    }
    merges
}

fn condense(
    n: usize,
    merges: &[(usize, usize, f64, usize)],
    min_cluster_size: usize,
) -> Vec<CondensedRow> {
    let root = n + merges.len() - 1;
    let size_of = |node: usize| if node < n { 1 } else { merges[node - n].3 };
    let children = |node: usize| (merges[node - n].0, merges[node - n].1);
    // Every leaf under `node`.
    let leaves = |node: usize, out: &mut Vec<usize>| {
        let mut stack = vec![node];
        while let Some(x) = stack.pop() {
            if x < n {
                out.push(x);
            } else {
                let (l, r) = children(x);
                stack.push(l);
                stack.push(r);
            }
        }
    };
    let mut label = vec![usize::MAX; n + merges.len()];
    label[root] = n;
    let mut next = n + 1;
    let mut rows = Vec::new();
    let mut queue = std::collections::VecDeque::from([root]);
    let mut fallen = Vec::new();
    while let Some(node) = queue.pop_front() {
        if node < n {
            continue;
        }
        let (left, right) = children(node);
        let distance = merges[node - n].2.max(MIN_DISTANCE);
        let lambda = 1.0 / distance;
        let here = label[node];
        let (big_left, big_right) = (
            size_of(left) >= min_cluster_size,
            size_of(right) >= min_cluster_size,
        );
        for (child, big, other_big) in [(left, big_left, big_right), (right, big_right, big_left)] {
            if big && other_big {
                label[child] = next;
                next += 1;
                rows.push(CondensedRow {
                    parent: here,
                    child: label[child],
                    lambda,
                    size: size_of(child),
                });
                queue.push_back(child);
            } else if big {
                // The cluster carries on through its big child.
                label[child] = here;
                queue.push_back(child);
            } else {
                fallen.clear();
                leaves(child, &mut fallen);
                for &point in &fallen {
                    rows.push(CondensedRow {
                        parent: here,
                        child: point,
                        lambda,
                        size: 1,
                    });
                }
            }
        }
    }
    rows
}

/// Excess-of-mass selection and labelling, as the Python package with default options.
fn select_and_label(n: usize, rows: &[CondensedRow], allow_single_cluster: bool) -> Clustering {
    let root = n;
    let clusters = rows
        .iter()
        .map(|r| r.parent.max(r.child))
        .max()
        .unwrap_or(root)
        + 1
        - n;
    let mut birth = vec![0.0f64; clusters];
    for r in rows.iter().filter(|r| r.child >= n) {
        birth[r.child - n] = r.lambda;
    }
    let mut stability = vec![0.0f64; clusters];
    for r in rows {
        stability[r.parent - n] += (r.lambda - birth[r.parent - n]) * r.size as f64;
    }
    let mut kids: Vec<Vec<usize>> = vec![Vec::new(); clusters];
    for r in rows.iter().filter(|r| r.child >= n) {
        kids[r.parent - n].push(r.child - n);
    }
    // Cluster ids are a topological order (children after parents): visit leaves first.
    let last = if allow_single_cluster { 0 } else { 1 };
    let mut selected = vec![false; clusters];
    for c in (last..clusters).rev() {
        selected[c] = true;
        let subtree: f64 = kids[c].iter().map(|&k| stability[k]).sum();
        if subtree > stability[c] {
            selected[c] = false;
            stability[c] = subtree;
        } else {
            let mut stack = kids[c].clone();
            while let Some(k) = stack.pop() {
                selected[k] = false;
                stack.extend_from_slice(&kids[k]);
            }
        }
    }
    let chosen: Vec<usize> = (0..clusters).filter(|&c| selected[c]).collect();
    let label_of = |c: usize| chosen.iter().position(|&x| x == c).map_or(-1, |i| i as i32);
    // Each point belongs to the nearest selected ancestor of the cluster it fell out of.
    let mut up = vec![usize::MAX; clusters];
    for r in rows.iter().filter(|r| r.child >= n) {
        up[r.child - n] = r.parent - n;
    }
    let owner: Vec<usize> = (0..clusters)
        .map(|c| {
            let mut x = c;
            loop {
                if selected[x] {
                    return x;
                }
                if up[x] == usize::MAX {
                    return usize::MAX;
                }
                x = up[x];
            }
        })
        .collect();
    let single_root = allow_single_cluster && chosen == [0];
    let root_max_lambda = rows
        .iter()
        .filter(|r| r.parent == root)
        .map(|r| r.lambda)
        .fold(0.0, f64::max);
    let mut labels = vec![-1i32; n];
    for r in rows.iter().filter(|r| r.child < n) {
        let c = owner[r.parent - n];
        if c == usize::MAX {
            continue;
        }
        if c == 0 && single_root {
            // Only the root's most persistent points join a single root cluster (as the
            // Python package does).
            if r.lambda >= root_max_lambda {
                labels[r.child] = label_of(0);
            }
        } else if c != 0 || allow_single_cluster {
            labels[r.child] = label_of(c);
        }
    }
    Clustering {
        labels,
        n_clusters: chosen.len(),
    }
}

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
    fn batched_knn_equals_per_point_knn() {
        let (points, _) = crate::group::blobs::blobs(3000, 8, 5, 1.0, 9);
        let data: Vec<f64> = points.iter().map(|&v| f64::from(v)).collect();
        let tree = KdTree::build(&data, 8);
        let all = tree.knn_all(10);
        for i in (0..3000).step_by(7) {
            let one = tree.knn(i, 10);
            let distances = |v: &[(f64, usize)]| v.iter().map(|x| x.0).collect::<Vec<_>>();
            assert_eq!(distances(&all[i]), distances(&one), "point {i}");
            assert_eq!(all[i][0], (0.0, i), "a point is its own nearest");
        }
    }
}
