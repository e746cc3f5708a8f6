"""The curriculum's stages (train_recon.stage_of), the fast unit vectors the model normalizes with
(gf.model.unit_vectors) and the bfloat16 forward pass (--bf16): `train/.venv/bin/python -m pytest -q
train/tests`."""

import sys
from pathlib import Path

import torch
from torch.nn import functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gf.model import GroupForwardMini, unit_vectors  # noqa: E402
from train_recon import float32, stage_of  # noqa: E402


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


def test_outputs_reach_the_losses_as_float32_and_absent_ones_stay_absent():
    outputs = float32((torch.ones(2, dtype=torch.bfloat16), None, torch.zeros(3)))
    assert outputs[0].dtype == torch.float32 and outputs[1] is None and outputs[2].dtype == torch.float32


def test_bfloat16_forward_stays_close_to_float32():
    # --bf16 trains with this forward and ships float32 weights: the two must agree to bfloat16's precision.
    torch.manual_seed(0)
    model = GroupForwardMini(mode='rgbd', room_gate=True).eval()
    images, points = torch.rand(1, 2, 3, 96, 128), torch.rand(1, 2, 3, 96, 128) * 4.0
    with torch.no_grad():
        depth, _, embeddings = model(images, points)
        with torch.autocast('cpu', dtype=torch.bfloat16):
            depth_bf16, _, embeddings_bf16 = float32(model(images, points))
    assert torch.isfinite(depth_bf16).all() and torch.isfinite(embeddings_bf16).all()
    assert ((depth_bf16 - depth).abs() / depth).median() < 0.02
    cosine = F.cosine_similarity(embeddings_bf16, embeddings, dim=2)
    assert cosine.median() > 0.98
