//! Association: which persistent instance each window instance is a sighting of. Scores combine
//! geometry (the share of points lying on each other, within a radius that follows the point
//! spacing) and semantics (prototype cosine), gated; one to one first (Kuhn–Munkres), then parts
//! (a leftover lying mostly on one instance joins it), then the duplicates a sighting reveals.

use pathfinding::prelude::{kuhn_munkres, Matrix};

use super::folds::names_an_object;
use super::footprint::Footprint;
use super::SceneMap;
use crate::frame::WindowInstance;
use crate::graph::instance::{bounds, cosine};

/// A window instance left over by the one-to-one matching is a part of a persistent instance
/// when at least this share of its points lies on it.
const PART_COVERED: f32 = 0.5;

/// A persistent instance is a duplicate a sighting reveals only when the sighting covers at
/// least this share of its points: the window grouped it with the instance it matched (one
/// object seen whole after two partial views). A sighting that only grazes a neighbour (a box
/// of a row, whose points lie within the overlap radius of its neighbour's face) is no evidence
/// that the two are one (layouts 96: three boxes side by side folded into one).
const DUPLICATE_COVERED: f32 = 0.5;

/// What association decided for one window.
#[derive(Debug)]
pub(super) struct Association {
    /// Per window instance, the persistent instance it is a sighting of (`None`: born).
    pub(super) pairs: Vec<Option<usize>>,
    /// Per window instance, whether its pair was found as a part (not one to one).
    pub(super) from_parts: Vec<bool>,
    /// Per window instance with a pair, the other persistent instances that passed the gate with
    /// it, are no window instance's pair, and of whose points it covers at least
    /// [`DUPLICATE_COVERED`]: the candidates for duplicates of its pair.
    covered: Vec<Vec<usize>>,
}

/// Associate `window` with `map`'s instances; `same_kind` (the vocabulary) says whether two
/// prototypes name one kind of object.
pub(super) fn associate(
    map: &SceneMap,
    window: &[WindowInstance],
    same_kind: &dyn Fn(&[f32], &[f32]) -> bool,
) -> Association {
    let p = map.params;
    let is_object = |prototype: &[f32]| names_an_object(same_kind, prototype);
    let window_footprints: Vec<Footprint> = window
        .iter()
        .map(|w| Footprint::new(&w.gaussians, p.voxel))
        .collect();
    // A persistent instance's footprint is built only when some window instance comes near
    // it: at 500 instances, building them all was most of a window's fusion.
    let map_bounds: Vec<_> = map.instances.iter().map(|m| bounds(&m.gaussians)).collect();
    let mut map_footprints: Vec<Option<Footprint>> =
        (0..map.instances.len()).map(|_| None).collect();
    // One to one first (Kuhn–Munkres): each persistent instance goes to the window instance
    // that scores best with it, so two window objects never both become one map object.
    let rows = window.len();
    let n = map.instances.len();
    let mut pairs: Vec<Option<usize>> = vec![None; rows];
    let mut from_parts = vec![false; rows];
    let mut gated: Vec<Vec<usize>> = vec![Vec::new(); rows];
    // Columns: every persistent instance, plus one "new instance" column per row so that
    // rows ≤ columns and birth is always possible (score 0).
    let scale = 1_000_000.0f32;
    let mut weights = Matrix::new(rows, n + rows, 0i64);
    for (i, wf) in window_footprints.iter().enumerate() {
        for j in 0..n {
            // A footprint's spacing is at most its bounds' diagonal (or the voxel), so
            // bounds farther apart than 1.5 × that overlap 0 whatever the footprint: the
            // gate below would drop the pair (1% margin against rounding).
            let (lo, hi) = map_bounds[j];
            let reach = 1.515 * wf.spacing.max((hi - lo).length()).max(p.voxel);
            if p.min_overlap > 0.0 && wf.apart(lo, hi, reach) {
                continue;
            }
            let mf = map_footprints[j]
                .get_or_insert_with(|| Footprint::new(&map.instances[j].gaussians, p.voxel));
            let radius = 1.5 * wf.spacing.max(mf.spacing);
            let overlap = wf.overlap(mf, radius);
            // Without semantics (no semantic model yet), geometry alone decides.
            let (a, b) = (&window[i].prototype, &map.instances[j].prototype);
            let similarity = (!a.is_empty() && !b.is_empty()).then(|| cosine(a, b));
            if overlap < p.min_overlap || similarity.is_some_and(|s| s < p.min_similarity) {
                continue;
            }
            // A sighting the vocabulary calls structure does not go into an object: a
            // cabinet's front, seen flat and named a wall once, turned the cabinet into
            // structure, which the object list leaves out.
            if !a.is_empty() && !is_object(a) && is_object(b) {
                continue;
            }
            let score = match similarity {
                Some(similarity) => {
                    p.geometry_weight * overlap + (1.0 - p.geometry_weight) * similarity
                }
                None => overlap,
            };
            gated[i].push(j);
            weights[(i, j)] = (score * scale).max(1.0) as i64;
        }
    }
    if rows > 0 && n > 0 {
        let (_, assignment) = kuhn_munkres(&weights);
        for (i, &j) in assignment.iter().enumerate() {
            if j < n && weights[(i, j)] > 0 {
                pairs[i] = Some(j);
            }
        }
    }
    // Then parts: a window instance left over whose points lie mostly on an instance it
    // passes the gate for (a table's leg split from its top by the window's grouping) joins
    // that instance instead of being born under a new id. A window instance that spans a
    // chair and the table beside it lies mostly on neither and is born.
    for i in 0..rows {
        if pairs[i].is_some() {
            continue;
        }
        let wf = &window_footprints[i];
        pairs[i] = gated[i]
            .iter()
            .filter_map(|&j| {
                // Built: gated pairs passed the geometry gate above.
                let mf = map_footprints[j].as_ref()?;
                Some((j, wf.covered_by(mf, 1.5 * wf.spacing.max(mf.spacing))))
            })
            .filter(|&(_, covered)| covered >= PART_COVERED)
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(j, _)| j);
        from_parts[i] = pairs[i].is_some();
    }
    // Coverage only for the few pairs that could be duplicates, once the pairs are known.
    let chosen: Vec<usize> = pairs.iter().flatten().copied().collect();
    let covered = (0..rows)
        .map(|i| {
            let Some(j) = pairs[i] else {
                return Vec::new();
            };
            let wf = &window_footprints[i];
            gated[i]
                .iter()
                .copied()
                .filter(|&other| other != j && !chosen.contains(&other))
                .filter(|&other| {
                    map_footprints[other].as_ref().is_some_and(|mf| {
                        mf.covered_by(wf, 1.5 * wf.spacing.max(mf.spacing)) >= DUPLICATE_COVERED
                    })
                })
                .collect()
        })
        .collect();
    Association {
        pairs,
        from_parts,
        covered,
    }
}

impl Association {
    /// Per window instance, the persistent instances that pass the gate for it but are no window
    /// instance's best, look like the one it chose and are covered by the sighting
    /// ([`DUPLICATE_COVERED`]): duplicates of one object (born when an earlier view overlapped too
    /// little). A window instance that spans two different objects (a chair the window grouped
    /// with its table) folds nothing.
    pub(super) fn duplicates(
        &self,
        map: &SceneMap,
        same_kind: &dyn Fn(&[f32], &[f32]) -> bool,
    ) -> Vec<Vec<usize>> {
        let p = map.params;
        let alike = |a: usize, b: usize| {
            let (pa, pb) = (&map.instances[a].prototype, &map.instances[b].prototype);
            pa.is_empty()
                || pb.is_empty()
                || (cosine(pa, pb) >= p.duplicate_similarity && same_kind(pa, pb))
        };
        self.pairs
            .iter()
            .zip(&self.covered)
            .map(|(pair, covered)| match pair {
                Some(j) => covered
                    .iter()
                    .copied()
                    .filter(|&other| alike(*j, other))
                    .collect(),
                None => Vec::new(),
            })
            .collect()
    }
}
