"""add_vote_output: an exported RGB-D model gains the output `votes`, equal to the PyTorch model's
centre votes, while its other outputs stay bit-identical (`make train-test`)."""

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from add_vote_output import add_votes  # noqa: E402
from gf.grouping import node_grouping  # noqa: E402
from gf.model import GroupForwardMini, cpu_session  # noqa: E402
from test_guided_upsampling import export, trained_like  # noqa: E402


def test_the_votes_output_matches_the_model_and_leaves_the_rest_alone(tmp_path):
    torch.manual_seed(2)
    model = trained_like(GroupForwardMini(mode='rgbd', room_gate=True))
    path = tmp_path / 'model.onnx'
    export(model, path)
    images, points = torch.rand(1, 2, 3, 96, 128), torch.randn(1, 2, 3, 96, 128) * 0.5
    feed = {'images': images.numpy(), 'points': points.numpy()}
    before = cpu_session(path, 1).run(['depth', 'gaussians', 'embeddings'], feed)
    assert add_votes(path)
    assert not add_votes(path), 'a second call adds nothing'
    after = cpu_session(path, 1).run(['depth', 'gaussians', 'embeddings', 'votes'], feed)
    for a, b in zip(before, after[:3]):
        np.testing.assert_array_equal(a, b)
    with torch.no_grad():
        votes = model.forward_with_votes(images, points)[3]
    assert after[3].shape == (1, 2, 3, 48, 64)
    np.testing.assert_allclose(after[3], votes.numpy(), atol=1e-4 * float(np.abs(votes.numpy()).max()))


def test_the_residual_pass_finding_nothing_leaves_the_noise_as_noise():
    # Two tight clusters and a few scattered points: the residual pass finds no cluster among them
    # (it indexed an empty array before).
    rng = np.random.default_rng(0)
    a = rng.normal([1, 0, 0], 0.01, (200, 3))
    b = rng.normal([0, 1, 0], 0.01, (200, 3))
    scattered = rng.normal(0, 1, (5, 3))
    e = np.concatenate([a, b, scattered]).astype(np.float32)
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    labels, _, _ = node_grouping(e)
    assert labels.shape == (405,)
    assert len(set(labels[:200])) == 1 and len(set(labels[200:400])) == 1


def test_the_vote_split_parts_a_row_of_three_and_keeps_the_room_whole():
    # The node's unit test (node/src/group/votes.rs) on the Python copy: three clumps of votes in a
    # row come apart (halving alone cut the middle one), the room (the largest cluster) stays one.
    from gf.grouping import vote_split
    rng = np.random.default_rng(1)
    room = rng.uniform(-1.5, 1.5, (400, 3))
    row = np.concatenate([rng.uniform(-0.1, 0.1, (60, 3)) + [x, 1.0, 0.5] for x in (2.0, 2.8, 3.6)])
    votes = np.concatenate([room, row])
    labels = np.r_[np.zeros(400, int), np.ones(180, int)]
    split = vote_split(labels, votes)
    assert (split[:400] == 0).all()
    parts = [set(split[400 + 60 * k:460 + 60 * k]) for k in range(3)]
    assert all(len(p) == 1 for p in parts) and len(set.union(*parts)) == 3
    blob = np.r_[np.zeros(400, int), np.ones(180, int)]
    spread = np.concatenate([room, rng.normal([2.8, 1.0, 0.5], 0.5, (180, 3))])
    assert (vote_split(blob, spread) == blob).all(), 'one spread blob stays one'


def test_the_room_gives_back_what_votes_above_the_floor_only_when_it_votes_below_it():
    # --room-votes (gf.grouping.room_give_back): a room cluster whose walls vote metres under the
    # floor (a model trained with --room-vote) gives back the cabinet voting above it; a room whose
    # votes lie around it (the shipped model's) gives back nothing.
    from gf.grouping import ROOM_VOTES, vote_split
    rng = np.random.default_rng(2)
    walls = rng.normal([0.0, 0.0, -3.0], 0.3, (400, 3))
    cabinet = rng.normal([1.0, 2.0, 0.5], 0.1, (80, 3))
    labels = np.zeros(480, int)
    given = vote_split(labels, np.concatenate([walls, cabinet]), room=ROOM_VOTES, floor=0.0)
    assert (given[:400] == 0).all() and len(set(given[400:])) == 1 and given[400] != 0
    around = np.concatenate([rng.uniform(-2, 2, (400, 3)), cabinet])
    assert (vote_split(labels, around, room=ROOM_VOTES, floor=0.0) == 0).all()
    assert (vote_split(labels, np.concatenate([walls, cabinet])) == 0).all(), 'off without room'
