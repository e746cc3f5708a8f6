"""The instance head's joint bilateral upsampling (GroupForwardMini.enable_guided_upsampling) and the
recovery of a checkpoint from an exported model (gf.recover): `make train-test`."""

import sys
from pathlib import Path

import pytest
import torch
from torch.nn import functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from export_recon import Contract  # noqa: E402
from gf.model import GroupForwardMini, bilateral_weights, joint_bilateral_upsample  # noqa: E402
from gf.recover import RecoveryError, recovered_model  # noqa: E402


def step_scene(height=8, width=16):
    """A colour step between columns 7 and 8 (a cell boundary at half resolution), and half-resolution
    values that step there too: what an object's silhouette against a wall looks like to the head."""
    guide = torch.zeros(1, 3, height, width)
    guide[..., width // 2:] = 1.0
    half = torch.zeros(1, 1, height // 2, width // 2)
    half[..., width // 4:] = 1.0
    return half, guide


def test_a_constant_stays_constant():
    half = torch.full((1, 4, 6, 8), 0.7)
    guide = torch.rand(1, 6, 12, 16)
    out = joint_bilateral_upsample(half, bilateral_weights(guide, torch.tensor(0.05), torch.tensor(0.05)))
    assert out.shape == (1, 4, 12, 16)
    assert torch.allclose(out, torch.full_like(out, 0.7), atol=1e-6)


def test_guided_upsampling_keeps_a_step_where_bilinear_blurs_it():
    half, guide = step_scene()
    bilinear = F.interpolate(half, scale_factor=2.0, mode='bilinear', align_corners=False)
    guided = joint_bilateral_upsample(half, bilateral_weights(guide, torch.tensor(1.0), torch.tensor(0.05)))
    # The pixel just left of the step takes a quarter of the right cell bilinearly.
    assert bilinear[0, 0, 3, 7] == pytest.approx(0.25)
    assert guided[0, 0, 3, 7] < 1e-3
    assert guided[0, 0, 3, 8] > 1.0 - 1e-3


def test_tiny_kernels_stay_finite():
    half, guide = step_scene()
    guide = guide + 0.01 * torch.rand_like(guide)
    out = joint_bilateral_upsample(half, bilateral_weights(guide, torch.tensor(1e-8), torch.tensor(1e-8)))
    assert torch.isfinite(out).all()
    # Every weight but the nearest guide's underflows: each pixel copies one neighbouring cell.
    assert ((out == 0.0) | (out == 1.0)).all()


def test_the_model_carries_its_upsampling_in_the_state_dict():
    torch.manual_seed(0)
    model = GroupForwardMini(mode='rgbd', room_gate=True).eval()
    images, points = torch.rand(1, 2, 3, 96, 128), torch.randn(1, 2, 3, 96, 128) * 0.5
    with torch.no_grad():
        bilinear = model(images, points)[2]
        model.enable_guided_upsampling(0.06, 0.05)
        guided = model(images, points)[2]
        reloaded = GroupForwardMini.from_state_dict(model.state_dict(), 'rgbd').eval()
        again = reloaded(images, points)[2]
    assert reloaded.guided_upsampling
    assert torch.equal(guided, again)
    assert not torch.allclose(guided, bilinear)
    assert torch.isfinite(guided).all()


def trained_like(model):
    """`model` with every parameter perturbed: an untrained one's GroupNorm affines are all ones and
    zeros, which the exporter stores once for all of them (a trained model's differ)."""
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.add_(0.01 * torch.randn_like(parameter))
    return model.eval()


def export(model, path):
    names = model.input_names()
    inputs = (torch.rand(1, 2, 3, 96, 128), torch.randn(1, 2, 3, 96, 128) * 0.5)
    torch.onnx.export(Contract(model, names), inputs, path, input_names=names,
                      output_names=['depth', 'gaussians', 'embeddings'], opset_version=17, dynamo=False)


def test_weights_are_recovered_from_an_exported_model(tmp_path):
    torch.manual_seed(1)
    model = trained_like(GroupForwardMini(mode='rgbd', room_gate=True))
    export(model, tmp_path / 'model.onnx')
    recovered = recovered_model(tmp_path / 'model.onnx', 'rgbd')
    for name, value in model.state_dict().items():
        assert torch.equal(recovered.state_dict()[name], value), name


def test_recovery_refuses_a_model_it_cannot_reproduce(tmp_path):
    torch.manual_seed(1)
    model = trained_like(GroupForwardMini(mode='rgbd', room_gate=True))
    model.enable_guided_upsampling(0.06, 0.05)
    export(model, tmp_path / 'model.onnx')
    # The upsampling's widths are folded into the graph's constants, not kept as a named weight:
    # recovery must refuse it rather than return a bilinear model's outputs.
    with pytest.raises(RecoveryError):
        recovered_model(tmp_path / 'model.onnx', 'rgbd')
