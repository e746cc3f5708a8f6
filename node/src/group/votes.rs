//! Splitting a window instance by its centre votes. The RGB-D model's instance head predicts, per
//! pixel, a 3D vote for its object's centre (ARCHITECTURE.md §5, output `votes`); its embeddings
//! are computed from those votes, but two identical objects side by side (a row of cabinets, two
//! desks touching) get embeddings too close for HDBSCAN to tell apart, while their votes still
//! point at two centres. On 60 `layouts` windows (scenes 40-99) the 183 pairs of identical
//! touching objects had vote centres a median 0.75 m apart with a median spread of 0.25 m
//! around them, and 2-means on the pair's votes split it at ARI 0.72 where the grouping's own
//! labels scored 0.24. `train/eval_recon.py --vote-split` scores this split on sim windows
//! (`gf.grouping.vote_split` mirrors it).
//!
//! A cluster splits in two when 2-means on its votes finds centres at least
//! [`VoteSplit::min_separation_m`] apart and at least [`VoteSplit::spread_ratio`] times the root
//! mean square distance of the votes to their centre (one compact blob of votes is one object,
//! however large), each part holding a fair share; the parts are tried again, so a row of four
//! comes apart in steps. The window's largest cluster is never split: it is the room (walls and
//! floor vote for the room's middle, widely spread).

use glam::Vec3;

/// When a window instance splits by its votes (see the module notes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoteSplit {
    /// The two parts' vote centres at least this far apart (m): objects side by side.
    pub min_separation_m: f32,
    /// ... and at least this many times the votes' root mean square distance to their part's
    /// centre: two clumps, not one spread blob. Chosen on the windows of `layouts` 40-99 and
    /// `val` 400-459, `realistic` included, by halving alone: 2.25 / 2.5 / 3 found 73.0 / 71.3 /
    /// 67.2% of the layouts objects against 64.6% unsplit, 92.7 / 92.4 / 92.1% of val's against
    /// 91.1%; with the Lloyd steps after it, 2.5 finds 71.7 and 92.7%.
    pub spread_ratio: f32,
    /// Each part holds at least this many points ...
    pub min_part_points: usize,
    /// ... and at least this share of the cluster's.
    pub min_part_share: f32,
    /// At most this many rounds of halving (a row of up to 2^rounds objects).
    pub max_rounds: usize,
}

impl Default for VoteSplit {
    fn default() -> Self {
        Self {
            min_separation_m: 0.3,
            spread_ratio: 2.5,
            min_part_points: 30,
            min_part_share: 0.1,
            max_rounds: 3,
        }
    }
}

/// Split the clusters of `labels` (per point: cluster index or -1) whose `votes` (per point, in
/// metres) form separate clumps; new clusters take the indices after the existing ones. The
/// largest cluster stays whole. Returns how many clusters were added. Non-finite votes never
/// split anything (a cluster with one stays whole).
pub fn split_by_votes(labels: &mut [i32], votes: &[Vec3], params: &VoteSplit) -> usize {
    if labels.len() != votes.len() {
        return 0;
    }
    let clusters = labels.iter().copied().max().map_or(0, |m| (m + 1).max(0)) as usize;
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); clusters];
    for (i, &label) in labels.iter().enumerate() {
        if label >= 0 {
            members[label as usize].push(i);
        }
    }
    let largest = (0..clusters).max_by_key(|&k| (members[k].len(), std::cmp::Reverse(k)));
    let mut next = clusters as i32;
    for (k, points) in members.into_iter().enumerate() {
        if Some(k) == largest || !points.iter().all(|&i| votes[i].is_finite()) {
            continue;
        }
        let parts = join_close_parts(
            refine(halve(points, votes, params, 0), votes),
            votes,
            params,
        );
        for part in parts.into_iter().skip(1) {
            for i in part {
                labels[i] = next;
            }
            next += 1;
        }
    }
    next as usize - clusters
}

/// The parts of one cluster's `points`: itself when its votes are one clump, else the parts of
/// each half.
fn halve(points: Vec<usize>, votes: &[Vec3], params: &VoteSplit, round: usize) -> Vec<Vec<usize>> {
    let enough = params.min_part_points.max(1);
    if round >= params.max_rounds || points.len() < 2 * enough {
        return vec![points];
    }
    let (side, centres) = two_means(&points, votes);
    let in_second = side.iter().filter(|&&s| s).count();
    let smaller = in_second.min(points.len() - in_second);
    let separation = centres[0].distance(centres[1]);
    let spread = (points
        .iter()
        .zip(&side)
        .map(|(&i, &s)| votes[i].distance_squared(centres[usize::from(s)]))
        .sum::<f32>()
        / points.len() as f32)
        .sqrt();
    let apart = separation >= params.min_separation_m && separation >= params.spread_ratio * spread;
    let fair = smaller >= enough && smaller as f32 >= params.min_part_share * points.len() as f32;
    if !(apart && fair) {
        return vec![points];
    }
    let (mut first, mut second) = (Vec::new(), Vec::new());
    for (i, s) in points.into_iter().zip(side) {
        if s { &mut second } else { &mut first }.push(i);
    }
    let mut parts = halve(first, votes, params, round + 1);
    parts.extend(halve(second, votes, params, round + 1));
    parts
}

/// Lloyd steps over all the parts of one cluster at once: each point goes to the part whose vote
/// centre is nearest. Halving a row of three cuts the middle object, one piece going with each
/// neighbour; this gives the pieces back to the middle part.
fn refine(mut parts: Vec<Vec<usize>>, votes: &[Vec3]) -> Vec<Vec<usize>> {
    if parts.len() < 2 {
        return parts;
    }
    let mut points: Vec<usize> = parts.iter().flatten().copied().collect();
    points.sort_unstable();
    for _ in 0..10 {
        let centres: Vec<Vec3> = parts
            .iter()
            .map(|p| p.iter().map(|&i| votes[i]).sum::<Vec3>() / p.len() as f32)
            .collect();
        let mut next: Vec<Vec<usize>> = vec![Vec::new(); parts.len()];
        for &i in &points {
            let nearest = (0..centres.len())
                .min_by(|&a, &b| {
                    votes[i]
                        .distance_squared(centres[a])
                        .total_cmp(&votes[i].distance_squared(centres[b]))
                })
                .unwrap_or(0);
            next[nearest].push(i);
        }
        next.retain(|p| !p.is_empty());
        let settled = next.len() == parts.len()
            && next.iter().zip(&parts).all(|(a, b)| {
                a.len() == b.len() && {
                    let mut b = b.clone();
                    b.sort_unstable();
                    *a == b
                }
            });
        parts = next;
        if settled {
            break;
        }
    }
    parts
}

/// Parts whose vote centres lie closer than [`VoteSplit::min_separation_m`] are one again,
/// closest first: halving a row of three cuts the middle object in two, each half going with a
/// neighbour, and the next round parts it from that neighbour.
fn join_close_parts(
    mut parts: Vec<Vec<usize>>,
    votes: &[Vec3],
    params: &VoteSplit,
) -> Vec<Vec<usize>> {
    let centre = |part: &[usize]| part.iter().map(|&i| votes[i]).sum::<Vec3>() / part.len() as f32;
    loop {
        let centres: Vec<Vec3> = parts.iter().map(|p| centre(p)).collect();
        let closest = (0..parts.len())
            .flat_map(|a| (a + 1..parts.len()).map(move |b| (a, b)))
            .map(|(a, b)| (centres[a].distance(centres[b]), a, b))
            .filter(|(d, _, _)| *d < params.min_separation_m)
            .min_by(|x, y| x.0.total_cmp(&y.0));
        let Some((_, a, b)) = closest else {
            return parts;
        };
        let joined = parts.swap_remove(b);
        parts[a].extend(joined);
    }
}

/// Deterministic 2-means on the votes of `points`: seeded with the vote farthest from their mean
/// and the vote farthest from that one, ten Lloyd steps. Returns per point whether it is in the
/// second part, and the two centres.
fn two_means(points: &[usize], votes: &[Vec3]) -> (Vec<bool>, [Vec3; 2]) {
    let mean = points.iter().map(|&i| votes[i]).sum::<Vec3>() / points.len() as f32;
    let farthest_from = |from: Vec3| {
        points
            .iter()
            .map(|&i| votes[i])
            .max_by(|a, b| {
                a.distance_squared(from)
                    .total_cmp(&b.distance_squared(from))
            })
            .unwrap_or(from)
    };
    let first = farthest_from(mean);
    let mut centres = [first, farthest_from(first)];
    let mut side = vec![false; points.len()];
    for _ in 0..10 {
        for (s, &i) in side.iter_mut().zip(points) {
            *s = votes[i].distance_squared(centres[1]) < votes[i].distance_squared(centres[0]);
        }
        let mut sums = [Vec3::ZERO; 2];
        let mut counts = [0usize; 2];
        for (&s, &i) in side.iter().zip(points) {
            sums[usize::from(s)] += votes[i];
            counts[usize::from(s)] += 1;
        }
        if counts.contains(&0) {
            break;
        }
        centres = [sums[0] / counts[0] as f32, sums[1] / counts[1] as f32];
    }
    (side, centres)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` votes around `centre`, spread evenly on a small cube of side `spread`.
    fn clump(centre: Vec3, n: usize, spread: f32) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let f = |k: usize| ((i * k) % 7) as f32 / 6.0 - 0.5;
                centre + spread * Vec3::new(f(1), f(3), f(5))
            })
            .collect()
    }

    /// The room's 400 votes (cluster 0, the largest) and one object cluster (1) of `clumps`
    /// (centre, votes, spread): votes and labels.
    fn room_and_one_cluster(clumps: &[(Vec3, usize, f32)]) -> (Vec<Vec3>, Vec<i32>) {
        let mut votes = clump(Vec3::ZERO, 400, 3.0);
        for &(centre, n, spread) in clumps {
            votes.extend(clump(centre, n, spread));
        }
        let labels = (0..votes.len()).map(|i| i32::from(i >= 400)).collect();
        (votes, labels)
    }

    #[test]
    fn a_row_of_three_clumps_comes_apart_and_the_room_stays_whole() {
        let row = [2.0, 2.8, 3.6].map(|x| (Vec3::new(x, 1.0, 0.5), 60, 0.2));
        let (votes, mut labels) = room_and_one_cluster(&row);
        let added = split_by_votes(&mut labels, &votes, &VoteSplit::default());
        assert_eq!(added, 2);
        assert!(labels[..400].iter().all(|&l| l == 0), "the room stays one");
        for part in labels[400..].chunks(60) {
            assert!(part.iter().all(|&l| l == part[0]), "{part:?}");
        }
        let mut distinct: Vec<i32> = labels[400..].iter().step_by(60).copied().collect();
        distinct.dedup();
        assert_eq!(distinct.len(), 3);
    }

    #[test]
    fn one_spread_blob_of_votes_stays_one_instance() {
        // A bed's votes, widely spread.
        let (votes, mut labels) = room_and_one_cluster(&[(Vec3::new(2.0, 1.0, 0.5), 200, 1.0)]);
        assert_eq!(
            split_by_votes(&mut labels, &votes, &VoteSplit::default()),
            0
        );
    }

    #[test]
    fn clumps_closer_than_the_separation_stay_one() {
        let (votes, mut labels) = room_and_one_cluster(&[
            (Vec3::new(2.0, 1.0, 0.5), 60, 0.02),
            (Vec3::new(2.2, 1.0, 0.5), 60, 0.02),
        ]);
        assert_eq!(
            split_by_votes(&mut labels, &votes, &VoteSplit::default()),
            0
        );
    }

    #[test]
    fn non_finite_or_mismatched_votes_split_nothing() {
        let (mut votes, mut labels) = room_and_one_cluster(&[
            (Vec3::new(2.0, 1.0, 0.5), 60, 0.2),
            (Vec3::new(3.0, 1.0, 0.5), 60, 0.2),
        ]);
        votes[450] = Vec3::NAN;
        assert_eq!(
            split_by_votes(&mut labels, &votes, &VoteSplit::default()),
            0
        );
        assert_eq!(
            split_by_votes(&mut labels, &votes[1..], &VoteSplit::default()),
            0
        );
        let mut empty: Vec<i32> = Vec::new();
        assert_eq!(split_by_votes(&mut empty, &[], &VoteSplit::default()), 0);
    }
}
