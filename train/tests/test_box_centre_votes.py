"""Votes for the centre of an object's whole box (gf.data.box_centre_map, vote_loss(box_centres=...))."""
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gf.data import POINTS_SCALE, box_centre_map  # noqa: E402
from gf.losses import vote_loss  # noqa: E402


def test_every_pixel_of_an_object_holds_its_box_centre_in_the_points_frame():
    # Two views, cameras at x = 0 and x = 2 (mean camera centre x = 1); object 3 spans x 1..3.
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, 0, 3] = 2.0
    instance = np.array([[[0, 3], [3, 7]], [[3, 0], [0, 0]]], np.uint16)
    objects = [{'instance_id': 3, 'bounds_min': [1.0, 0.0, 4.0], 'bounds_max': [3.0, 1.0, 5.0]}]
    centres = box_centre_map(instance, objects, poses)
    assert centres.shape == (2, 3, 2, 2)
    expected = np.array([1.0, 0.5, 4.5]) / POINTS_SCALE
    for view, row, col in [(0, 0, 1), (0, 1, 0), (1, 0, 0)]:
        assert np.allclose(centres[view, :, row, col], expected)
    # The room and an id no object lists (7) get no target, finite.
    assert np.all(centres[0, :, 0, 0] == 0.0) and np.all(centres[0, :, 1, 1] == 0.0)
    assert np.isfinite(centres).all()


def test_a_piece_voting_for_its_box_centre_costs_nothing_though_its_centroid_is_elsewhere():
    # One view 4x4 at full resolution (2x2 at the votes'), object 1 fills it; its visible points lie
    # around x = 0 but its box centre is at x = 1: a vote for the box centre costs nothing with
    # box_centres and about 1 without.
    instance = torch.ones(1, 1, 4, 4, dtype=torch.long)
    depth = torch.ones(1, 1, 4, 4)
    points = torch.zeros(1, 1, 3, 4, 4)
    box_centres = torch.zeros(1, 1, 3, 4, 4)
    box_centres[:, :, 0] = 1.0
    votes = torch.zeros(1, 1, 3, 2, 2)
    votes[:, :, 0] = 1.0
    assert vote_loss(votes, points, depth, instance, box_centres=box_centres).item() < 1e-6
    assert abs(vote_loss(votes, points, depth, instance).item() - 1.0) < 1e-6
