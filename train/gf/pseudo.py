"""Pseudo instance labels when ground-truth instances are missing (the paper's path).

Each view gets its own masks with ids that do not agree across views, as a per-view segmenter such as
SAM2 gives them (`per_view_masks`). `associate` makes the ids agree through geometry: every mask's
pixels are lifted with the stage-1 predicted depth and the cameras, projected into every other view,
correspondences whose depth disagrees with that view's predicted depth (occluded, or wrong depth) are
discarded, and two masks are joined when each is the other's best match by projected overlap and the
overlap covers at least `min_overlap` of the smaller one's consistent projections. Joins are
transitive (union-find), so a window's masks become window-wide instances.
"""

import numpy as np


def per_view_masks(instance, rng):
    """Relabel each view's instance map [V,H,W] with fresh random ids (no agreement across views)."""
    out = np.empty_like(instance)
    next_id = 0
    for v in range(instance.shape[0]):
        ids, inverse = np.unique(instance[v], return_inverse=True)
        fresh = rng.permutation(len(ids)) + next_id
        out[v] = fresh[inverse.reshape(instance[v].shape)]
        next_id += len(ids)
    return out


def _lift(depth, k, pose):
    height, width = depth.shape
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    camera = np.stack([(u - k[0, 2]) / k[0, 0] * depth, (v - k[1, 2]) / k[1, 1] * depth, depth], axis=-1)
    return camera.reshape(-1, 3) @ pose[:3, :3].T + pose[:3, 3]


def _project(points, k, pose, height, width):
    camera = (points - pose[:3, 3]) @ pose[:3, :3]
    z = camera[:, 2]
    safe = np.where(z > 1e-6, z, 1.0)
    u = np.round(k[0, 0] * camera[:, 0] / safe + k[0, 2]).astype(np.int64)
    v = np.round(k[1, 1] * camera[:, 1] / safe + k[1, 2]).astype(np.int64)
    inside = (z > 1e-6) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    return u, v, z, inside


def associate(masks, depth, intrinsics, poses, depth_tolerance=0.1, min_overlap=0.3):
    """Window-wide ids [V,H,W] from per-view `masks` [V,H,W], predicted `depth` [V,H,W] (metres),
    `intrinsics` [V,3,3] and `poses` (world_from_camera) [V,4,4]."""
    views, height, width = masks.shape
    ids, dense = np.unique(masks, return_inverse=True)
    dense = dense.reshape(masks.shape)
    parent = list(range(len(ids)))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for i in range(views):
        points = _lift(depth[i], intrinsics[i], poses[i])
        source = dense[i].reshape(-1)
        valid = np.isfinite(depth[i].reshape(-1)) & (depth[i].reshape(-1) > 0)
        for j in range(views):
            if i == j:
                continue
            u, v, z, inside = _project(points, intrinsics[j], poses[j], height, width)
            keep = inside & valid
            target_depth = depth[j][v[keep], u[keep]]
            consistent = np.abs(target_depth - z[keep]) <= depth_tolerance * z[keep]
            a = source[keep][consistent]
            b = dense[j][v[keep][consistent], u[keep][consistent]]
            if a.size == 0:
                continue
            overlap = np.bincount(a * len(ids) + b, minlength=len(ids) ** 2).reshape(len(ids), len(ids))
            projected = overlap.sum(1)
            for m in np.nonzero(projected)[0]:
                best = overlap[m].argmax()
                # Mutual best and a large enough share of the projection.
                if overlap[:, best].argmax() == m and overlap[m, best] >= min_overlap * projected[m]:
                    parent[find(m)] = find(best)
    roots = np.array([find(a) for a in range(len(ids))])
    return roots[dense]
