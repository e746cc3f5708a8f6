//! From the spanning tree to labels: single linkage, the condensed tree with
//! `min_cluster_size`, and excess-of-mass selection.

use super::mst::find;

/// Distances below this are treated as this, so λ = 1/d stays finite for duplicate points.
const MIN_DISTANCE: f64 = 1e-12;

/// Labels (`-1` noise, clusters `0..n_clusters`) in input order.
#[derive(Debug, Clone, PartialEq)]
pub struct Clustering {
    pub labels: Vec<i32>,
    pub n_clusters: usize,
}

/// One row of the condensed tree: `child` (a point < n, or a cluster ≥ n) leaves `parent` at
/// `lambda` = 1 / distance with `size` points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct CondensedRow {
    pub(super) parent: usize,
    pub(super) child: usize,
    pub(super) lambda: f64,
    pub(super) size: usize,
}

/// Single-linkage merges (left, right, distance, size) from MST edges over `weights.len()` points
/// (a point stands for `weights[i]` embeddings); node ids ≥ n are merges.
pub(super) fn single_linkage(
    weights: &[usize],
    mut edges: Vec<(usize, usize, f64)>,
) -> Vec<(usize, usize, f64, usize)> {
    let n = weights.len();
    edges.sort_by(|x, y| x.2.total_cmp(&y.2).then((x.0, x.1).cmp(&(y.0, y.1))));
    let mut parent: Vec<usize> = (0..2 * n).collect();
    let mut size = vec![1usize; 2 * n];
    size[..n].copy_from_slice(weights);
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

/// The condensed tree: a point falls out of its cluster with its weight as `size`. A point that
/// weighs a cluster's size alone (a grid cell of at least `min_cluster_size` embeddings) carries
/// its cluster on to `leaf_lambda` (1 / the grid's resolution: below it the cell's embeddings are
/// not told apart), or to where it split off if that is later.
pub(super) fn condense(
    weights: &[usize],
    merges: &[(usize, usize, f64, usize)],
    min_cluster_size: usize,
    leaf_lambda: f64,
) -> Vec<CondensedRow> {
    let n = weights.len();
    let root = n + merges.len() - 1;
    let size_of = |node: usize| {
        if node < n {
            weights[node]
        } else {
            merges[node - n].3
        }
    };
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
    let mut queue = std::collections::VecDeque::from([(root, 0.0f64)]);
    let mut fallen = Vec::new();
    while let Some((node, entered)) = queue.pop_front() {
        if node < n {
            rows.push(CondensedRow {
                parent: label[node],
                child: node,
                lambda: entered.max(leaf_lambda),
                size: weights[node],
            });
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
                queue.push_back((child, lambda));
            } else if big {
                // The cluster carries on through its big child.
                label[child] = here;
                queue.push_back((child, lambda));
            } else {
                fallen.clear();
                leaves(child, &mut fallen);
                for &point in &fallen {
                    rows.push(CondensedRow {
                        parent: here,
                        child: point,
                        lambda,
                        size: weights[point],
                    });
                }
            }
        }
    }
    rows
}

/// Excess-of-mass selection and labelling, as the Python package with default options.
pub(super) fn select_and_label(
    n: usize,
    rows: &[CondensedRow],
    allow_single_cluster: bool,
) -> Clustering {
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
