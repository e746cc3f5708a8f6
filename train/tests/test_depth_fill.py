"""The RGB-D model's training input fills dropped depth as the node does (tests/tests/depth_fill_parity.rs
holds the two fills bit for bit): a window with holes gives the points of the hole-free window wherever the
hole's filled depth equals the true depth, and no pixel sits at the neutral centre any more."""

import numpy as np

from gf.data import world_points
from gf.depth_fill import fill_invalid_depth


def _window():
    k = np.array([[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]])
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, 0, 3] = 0.3
    depth = np.full((2, 24, 32), 2.5, np.float32)
    return depth, np.stack([k, k]), poses


def test_holes_in_a_flat_wall_are_filled_with_the_wall():
    depth, k, poses = _window()
    clean = world_points(depth, k, poses)
    holed = depth.copy()
    rng = np.random.default_rng(0)
    holed[rng.random(holed.shape) < 0.3] = 0.0
    holed[0, 5:15, 5:20] = np.nan
    np.testing.assert_allclose(world_points(holed, k, poses), clean, atol=1e-6)


def test_a_view_without_valid_depth_stays_at_the_centre():
    depth, k, poses = _window()
    depth[1] = 0.0
    points = world_points(depth, k, poses)
    assert np.all(points[1] == 0.0)
    assert np.all(np.isfinite(points))
    assert not np.any(np.all(points[0] == 0.0, axis=0))


def test_edge_holes_take_the_background():
    d = np.array([[1.0, 0.0, 3.0]], np.float32)
    assert fill_invalid_depth(d).tolist() == [[1.0, 3.0, 3.0]]
