"""Checks of the posed RGB model's plane sweep (gf.model.plane_sweep_cost) on a synthetic textured
plane, where the right answer is known: `train/.venv/bin/python -m pytest -q train/tests`."""

import math
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gf import model as gf_model  # noqa: E402
from gf.data import POINTS_SCALE  # noqa: E402

HEIGHT, WIDTH = 96, 128
K = torch.tensor([[64.0, 0.0, 63.5], [0.0, 64.0, 47.5], [0.0, 0.0, 1.0]])


def poses(translations_m):
    """World-from-camera poses [1,V,4,4] of cameras looking along world +z, translations in metres
    (converted to the points' frame)."""
    out = torch.eye(4).repeat(len(translations_m), 1, 1)
    out[:, :3, 3] = torch.tensor(translations_m) / POINTS_SCALE
    return out[None]


def plane_texture(cameras, plane_depth_m):
    """Unit features [1,V,C,h,w] at half resolution: a smooth texture of the world x, y where each
    pixel's ray meets the plane z = plane_depth_m (every camera sits at z = 0)."""
    v = cameras.shape[1]
    h, w = HEIGHT // 2, WIDTH // 2
    ys = (torch.arange(h) + 0.5) * 2 - 0.5
    xs = (torch.arange(w) + 0.5) * 2 - 0.5
    ray_x = ((xs - K[0, 2]) / K[0, 0])[None, :].expand(h, w)
    ray_y = ((ys - K[1, 2]) / K[1, 1])[:, None].expand(h, w)
    features = []
    for i in range(v):
        t = cameras[0, i, :3, 3] * POINTS_SCALE
        x, y = t[0] + plane_depth_m * ray_x, t[1] + plane_depth_m * ray_y
        channels = [f(s * c) for s in (3.0, 7.0, 13.0) for c in (x, y) for f in (torch.sin, torch.cos)]
        features.append(torch.nn.functional.normalize(torch.stack(channels), dim=0))
    return torch.stack(features)[None]


def sweep(features, cameras):
    v = cameras.shape[1]
    return gf_model.plane_sweep_cost(features, K.expand(1, v, 3, 3), cameras, HEIGHT, WIDTH)


def plane_depths():
    return 1 / gf_model.sweep_inverse_depths()


def test_plane_sweep_finds_a_textured_plane():
    cameras = poses([[0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [0.0, 0.2, 0.0]])
    depth = 3.0
    cost = sweep(plane_texture(cameras, depth), cameras)
    assert cost.shape == (1, 3, gf_model.SWEEP_PLANES, HEIGHT // 2, WIDTH // 2)
    assert torch.isfinite(cost).all()
    nearest = (plane_depths() - depth).abs().argmin()
    # Away from the borders (where the other views do not see the plane) the best plane is the true one.
    inner = cost[0, :, :, 8:-8, 8:-8]
    best = inner.argmax(1)
    assert (best == nearest).float().mean() > 0.95
    assert inner[:, nearest].mean() > 0.95


def test_plane_sweep_wrong_poses_do_not_match():
    cameras = poses([[0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [0.0, 0.2, 0.0]])
    features = plane_texture(cameras, 3.0)
    swapped = cameras[:, [1, 2, 0]]  # each view given another view's pose
    nearest = (plane_depths() - 3.0).abs().argmin()
    assert sweep(features, swapped)[0, :, nearest, 8:-8, 8:-8].mean() < 0.5


def test_plane_sweep_single_view_is_zero_not_nan():
    cameras = poses([[0.0, 0.0, 0.0]])
    cost = sweep(plane_texture(cameras, 3.0), cameras)
    assert torch.isfinite(cost).all() and cost.abs().max() == 0


def test_plane_sweep_pure_rotation_and_identical_poses_stay_finite():
    # Identical poses: no parallax, every plane matches alike (nothing to triangulate, nothing wrong).
    same = poses([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    cost = sweep(plane_texture(same, 3.0), same)
    assert torch.isfinite(cost).all()
    # A view turned away sees none of the other's points: its cost is 0, not NaN.
    turned = same.clone()
    angle = math.pi
    turned[0, 1, :3, :3] = torch.tensor([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0],
                                         [-math.sin(angle), 0, math.cos(angle)]])
    cost = sweep(plane_texture(same, 3.0), turned)
    assert torch.isfinite(cost).all() and cost.abs().max() == 0
