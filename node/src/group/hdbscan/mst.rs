//! The minimum spanning tree of the mutual-reachability graph: Borůvka rounds over the KD-tree,
//! with pruning by component, by bound and by core distance.

use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use super::kdtree::{consider, push_nearer_last, KdTree};

/// Union-find root, with path halving.
pub(super) fn find(parent: &mut [usize], mut x: usize) -> usize {
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
pub(super) fn mutual_reachability_mst(
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
