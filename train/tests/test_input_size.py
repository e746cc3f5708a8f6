"""A model taken to a larger input than it was trained at (GroupForwardMini.set_input_size,
export_recon.py --input-size): `make train-test`."""

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from export_recon import input_size  # noqa: E402
from gf.model import GroupForwardMini, example_inputs, positional_encoding  # noqa: E402


def test_a_finer_grid_samples_the_trained_positions_in_between():
    trained = positional_encoding(6, 8, 32)
    finer = positional_encoding(12, 16, 32, span=(6, 8))
    # Every other token of the finer grid sits exactly on a trained one.
    assert torch.allclose(finer[:, ::2, ::2], trained, atol=1e-6)
    # The ones between are new positions inside the trained range, not beyond its end.
    beyond = positional_encoding(12, 16, 32)
    assert not torch.allclose(finer[:, 1::2, 1::2], beyond[:, 6:, 8:], atol=1e-3)


def test_a_model_at_a_larger_input_gives_outputs_at_that_size():
    torch.manual_seed(0)
    model = GroupForwardMini('rgbd', centre_votes=True, room_gate=True).eval()
    trained = model.position.clone()
    model.set_input_size(144, 192)
    # 9 x 12 tokens over the trained 6 x 8: every third sits on every other trained one.
    assert torch.allclose(model.position[:, ::3, ::3], trained[:, ::2, ::2], atol=1e-6)
    inputs = example_inputs(model.input_names(), 2, torch.Generator().manual_seed(0), 144, 192)
    with torch.no_grad():
        depth, gaussians, embeddings = model(**inputs)
    assert depth.shape[-2:] == (144, 192)
    assert gaussians.shape[-2:] == (144, 192)
    assert embeddings.shape[-2:] == (144, 192)
    assert torch.isfinite(embeddings).all() and torch.isfinite(depth).all()


def test_sizes_off_the_token_grid_or_the_aspect_are_refused():
    model = GroupForwardMini('rgbd')
    with pytest.raises(ValueError, match='multiples of 16'):
        model.set_input_size(120, 160)
    with pytest.raises(ValueError, match='aspect'):
        model.set_input_size(144, 256)
    assert input_size('192x144') == (192, 144)
    with pytest.raises(Exception, match='WIDTHxHEIGHT'):
        input_size('192')
