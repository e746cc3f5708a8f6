"""The curriculum's stages (train_recon.stage_of) and the fast unit vectors the model normalizes with
(gf.model.unit_vectors): `train/.venv/bin/python -m pytest -q train/tests`."""

import sys
from pathlib import Path

import torch
from torch.nn import functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gf.model import unit_vectors  # noqa: E402
from train_recon import stage_of  # noqa: E402


def stages(split, polish=0.0, steps=100):
    return [stage_of(step / steps, split, polish) for step in range(steps)]


def test_three_stages_in_order_by_their_shares():
    sequence = stages([0.15, 0.25, 0.6])
    assert sequence == [1] * 15 + [2] * 25 + [3] * 60


def test_polish_takes_the_last_share_and_the_stages_split_the_rest():
    sequence = stages([0.15, 0.25, 0.6], polish=0.2)
    assert sequence == [1] * 12 + [2] * 20 + [3] * 48 + [4] * 20


def test_head_only_fine_tune_never_polishes():
    assert set(stages([0.0, 1.0, 0.0])) == {2}


def test_unit_vectors_match_f_normalize():
    x = torch.randn(2, 8, 6, 5)
    torch.testing.assert_close(unit_vectors(x), F.normalize(x, dim=1))
    torch.testing.assert_close(unit_vectors(x.transpose(0, 3), dim=3), F.normalize(x.transpose(0, 3), dim=3))


def test_unit_vectors_of_zero_vectors_stay_finite_with_finite_gradients():
    x = torch.zeros(1, 4, 3, 3, requires_grad=True)
    y = unit_vectors(x, eps=1e-6)
    y.sum().backward()
    assert torch.all(y == 0)
    assert torch.isfinite(x.grad).all()
