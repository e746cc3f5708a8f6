"""The node's grouping (node/src/group `group`) in numpy + hdbscan, for scoring models exactly as the
node groups them. No torch: tests/tests/grouping_parity.rs runs it from the test venv and holds it
against the Rust implementation on fixed embeddings."""

import hdbscan
import numpy as np

MAX_CLUSTER_POINTS = 20_000
# min_cluster_size, min_samples, noise distance, merge distance: chosen together on the 24 selection
# windows (train/README.md), as the node's GroupingParams::default.
GROUPING = (30, 10, 0.7, 0.4)


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


def node_grouping(embeddings, grouping=GROUPING):
    """Labels per row of unit `embeddings` [N,D] as node/src/group `group` computes them; and
    HDBSCAN's own labels on the subsample with the subsample's indices."""
    min_cluster_size, min_samples, noise_distance, merge_distance = grouping
    n = embeddings.shape[0]
    stride = max(1, -(-n // MAX_CLUSTER_POINTS))
    sample = np.arange(0, n, stride)
    raw = hdbscan.HDBSCAN(min_cluster_size=int(min_cluster_size), min_samples=int(min_samples),
                          allow_single_cluster=True).fit_predict(embeddings[sample].astype(np.float64))
    clusters = np.unique(raw[raw >= 0])
    if clusters.size == 0:
        return np.full(n, -1), raw, sample
    sums = [embeddings[sample][raw == k].sum(0) for k in clusters]
    centroids = merge_close_clusters(sums, merge_distance)
    distances = np.sqrt(np.maximum(
        (embeddings ** 2).sum(1)[:, None] - 2 * embeddings @ centroids.T + (centroids ** 2).sum(1)[None], 0))
    nearest = distances.argmin(1)
    labels = np.where(distances[np.arange(n), nearest] <= noise_distance, nearest, -1)
    return labels, raw, sample
