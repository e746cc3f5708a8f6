"""The node's grouping (node/src/group `group`) in numpy + hdbscan, for scoring models exactly as the
node groups them. No torch: tests/tests/grouping_parity.rs runs it from the test venv and holds it
against the Rust implementation on fixed embeddings."""

import hdbscan
import numpy as np

MAX_CLUSTER_POINTS = 20_000
# min_cluster_size, min_samples, noise distance, merge distance: chosen together on the 24 selection
# windows (train/README.md), as the node's GroupingParams::default.
GROUPING = (30, 10, 0.7, 0.4)
# The node's default ResidualPass: min_cluster_size, min_samples, noise distance.
RESIDUAL = (15, 5, 0.35)
# The node runs HDBSCAN on a grid of its embeddings (GroupingParams::resolution, 0.005: a cell's
# embeddings one point weighted by their number); hdbscan takes no weights, so this copy clusters
# every embedding. The two differ only below the resolution: after the centroids' assignment they
# agree at ARI >= 0.996 on benchmark windows, and exactly on the parity test's fixture.


def unit_centroids(embeddings, labels, ids):
    """The mean of the unit `embeddings` [N,D] per label in `ids`, renormalised to unit length."""
    centroids = np.stack([embeddings[labels == k].mean(0) for k in ids])
    return centroids / np.maximum(np.linalg.norm(centroids, axis=1, keepdims=True), 1e-12)


def merge_close_clusters(sums, merge_distance):
    """node/src/group `merge_close_clusters`: unit centroids of K ≥ 1 clusters given by their member
    sums [K,D], joining the closest pair while it is at most `merge_distance` apart."""
    sums = [s.astype(np.float64) for s in sums]
    unit = lambda s: s / max(np.linalg.norm(s), 1e-12)  # noqa: E731
    centroids = [unit(s) for s in sums]
    while len(centroids) > 1:
        c = np.stack(centroids)
        distances = np.linalg.norm(c[:, None] - c[None], axis=2) + np.tril(np.full((len(c),) * 2, np.inf))
        a, b = np.unravel_index(distances.argmin(), distances.shape)
        if distances[a, b] > merge_distance:
            break
        sums[a] = sums[a] + sums[b]
        sums[b] = sums[-1]
        sums.pop()
        centroids[b] = centroids[-1]
        centroids.pop()
        centroids[a] = unit(sums[a])
    return np.stack(centroids)


def cluster_and_assign(embeddings, members, density, noise_distance, merge_distance):
    """node/src/group `cluster_and_assign`: HDBSCAN on an even stride through the rows `members` of
    the unit `embeddings`, close clusters merged, then each member's nearest centroid (or -1 beyond
    the noise distance). Returns the members' labels, the centroids, HDBSCAN's labels and the
    subsample's indices."""
    min_cluster_size, min_samples = density
    stride = max(1, -(-len(members) // MAX_CLUSTER_POINTS))
    sample = members[::stride]
    if len(sample) < min_cluster_size:  # no cluster can form (hdbscan itself refuses so few)
        return np.full(len(members), -1), np.zeros((0, embeddings.shape[1])), np.full(len(sample), -1), sample
    raw = hdbscan.HDBSCAN(min_cluster_size=int(min_cluster_size), min_samples=int(min_samples),
                          allow_single_cluster=True).fit_predict(embeddings[sample].astype(np.float64))
    clusters = np.unique(raw[raw >= 0])
    if clusters.size == 0:
        return np.full(len(members), -1), np.zeros((0, embeddings.shape[1])), raw, sample
    sums = [embeddings[sample][raw == k].sum(0) for k in clusters]
    centroids = merge_close_clusters(sums, merge_distance)
    e = embeddings[members]
    distances = np.sqrt(np.maximum(
        (e ** 2).sum(1)[:, None] - 2 * e @ centroids.T + (centroids ** 2).sum(1)[None], 0))
    nearest = distances.argmin(1)
    labels = np.where(distances[np.arange(len(members)), nearest] <= noise_distance, nearest, -1)
    return labels, centroids, raw, sample


def node_grouping(embeddings, grouping=GROUPING, residual=RESIDUAL):
    """Labels per row of unit `embeddings` [N,D] as node/src/group `group` computes them (with the
    node's ResidualPass when `residual` is (min_cluster_size, min_samples, noise distance), as by
    default; None: the first pass alone);
    and the first HDBSCAN's own labels on its subsample with the subsample's indices."""
    min_cluster_size, min_samples, noise_distance, merge_distance = grouping
    everything = np.arange(embeddings.shape[0])
    labels, centroids, raw, sample = cluster_and_assign(
        embeddings, everything, (min_cluster_size, min_samples), noise_distance, merge_distance)
    if residual is not None:
        noise = everything[labels < 0]
        size, samples, residual_distance = residual
        more, extra, _, _ = cluster_and_assign(embeddings, noise, (size, samples), residual_distance, merge_distance)
        counts = np.bincount(more[more >= 0], minlength=len(extra))
        kept = counts >= size
        renamed = np.where(kept, len(centroids) + np.cumsum(kept) - 1, -1)
        # With no residual cluster at all `renamed` is empty: the noise stays noise.
        labels[noise] = np.where(more >= 0, renamed[np.maximum(more, 0)], -1) if len(renamed) else -1
    return labels, raw, sample


# node/src/group/votes.rs `VoteSplit::default`: minimum separation (m), spread ratio, minimum part
# points, minimum part share, rounds of halving.
VOTE_SPLIT = (0.3, 2.5, 30, 0.1, 3)
# A model trained with a room vote target (train_recon.py --room-vote) has walls and floor vote
# for a point metres below the floor. The window's largest cluster is that room when at least
# `share` of its votes lie `below` (m) under the floor; its points voting above the floor less
# `margin` (m) are objects the grouping gave the room.
ROOM_VOTES = (1.0, 0.5, 0.25)


def _two_means(votes):
    """node `two_means`: seeded with the vote farthest from the mean and the one farthest from it."""
    first = votes[np.argmax(((votes - votes.mean(0)) ** 2).sum(1))]
    centres = np.stack([first, votes[np.argmax(((votes - first) ** 2).sum(1))]])
    side = np.zeros(len(votes), bool)
    for _ in range(10):
        side = ((votes - centres[1]) ** 2).sum(1) < ((votes - centres[0]) ** 2).sum(1)
        if side.all() or not side.any():
            break
        centres = np.stack([votes[~side].mean(0), votes[side].mean(0)])
    return side, centres


def _halve(points, votes, split, round_=0):
    separation_m, ratio, min_points, min_share, rounds = split
    if round_ >= rounds or len(points) < 2 * max(min_points, 1):
        return [points]
    side, centres = _two_means(votes[points])
    smaller = min(side.sum(), len(points) - side.sum())
    separation = np.linalg.norm(centres[0] - centres[1])
    spread = np.sqrt(((votes[points] - centres[side.astype(int)]) ** 2).sum(1).mean())
    if not (separation >= separation_m and separation >= ratio * spread
            and smaller >= max(min_points, 1) and smaller >= min_share * len(points)):
        return [points]
    return _halve(points[~side], votes, split, round_ + 1) + _halve(points[side], votes, split, round_ + 1)


def _refine(parts, votes):
    """node `refine`: Lloyd steps over all the parts of one cluster."""
    points = np.sort(np.concatenate(parts))
    for _ in range(10):
        centres = np.stack([votes[p].mean(0) for p in parts])
        nearest = ((votes[points][:, None] - centres[None]) ** 2).sum(2).argmin(1)
        new = [points[nearest == k] for k in range(len(parts)) if (nearest == k).any()]
        settled = len(new) == len(parts) and all(np.array_equal(a, np.sort(b)) for a, b in zip(new, parts))
        parts = new
        if settled:
            break
    return parts


def _join_close(parts, votes, separation_m):
    while len(parts) > 1:
        centres = np.stack([votes[p].mean(0) for p in parts])
        d = np.linalg.norm(centres[:, None] - centres[None], axis=2) + np.tril(np.full((len(parts),) * 2, np.inf))
        a, b = np.unravel_index(d.argmin(), d.shape)
        if d[a, b] >= separation_m:
            break
        parts[a] = np.concatenate([parts[a], parts[b]])
        parts[b] = parts[-1]
        parts.pop()
    return parts


def room_give_back(labels, votes, largest, floor, room=ROOM_VOTES, min_points=VOTE_SPLIT[2]):
    """The points of cluster `largest` voting above the floor (height `floor`, the votes' frame)
    while most of it votes under it (ROOM_VOTES) become a new cluster of `labels` (in place)."""
    below, share, margin = room
    points = np.flatnonzero(labels == largest)
    v = votes[points]
    if points.size == 0 or not np.isfinite(v).all() or not np.isfinite(floor):
        return
    out = points[v[:, 2] > floor - margin]
    if (v[:, 2] < floor - below).mean() >= share and out.size >= max(min_points, 1):
        labels[out] = labels.max() + 1


def vote_split(labels, votes, split=VOTE_SPLIT, room=None, floor=np.nan):
    """node/src/group/votes.rs `split_by_votes`: `labels` (per point, -1 noise) with every cluster
    but the largest split where its `votes` [N,3] (metres) form separate clumps; new clusters take
    the next labels. (Ties in the nearest-part and the closest-pair searches may resolve otherwise
    than in the node; the rule is the same.)"""
    labels = labels.copy()
    if labels.size == 0 or labels.max() < 0:
        return labels
    counts = np.bincount(labels[labels >= 0])
    largest = counts.argmax()
    if room is not None:
        room_give_back(labels, votes, largest, floor, room, split[2])
        counts = np.bincount(labels[labels >= 0])
    following = len(counts)
    for k in range(len(counts)):
        points = np.flatnonzero(labels == k)
        if k == largest or points.size == 0 or not np.isfinite(votes[points]).all():
            continue
        parts = _halve(points, votes, split)
        if len(parts) > 1:
            parts = _join_close(_refine(parts, votes), votes, split[0])
        for part in parts[1:]:
            labels[part] = following
            following += 1
    return labels
