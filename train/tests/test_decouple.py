"""The decoupled recipe (train_recon.py --decouple): instance losses must train the instance head and
leave the depth path untouched: `train/.venv/bin/python -m pytest -q train/tests`."""

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gf.model import GroupForwardMini  # noqa: E402


def instance_loss_gradients(instance_gradient):
    """Gradient norms, per parameter group, of a loss on the embeddings and room logits alone."""
    torch.manual_seed(0)
    model = GroupForwardMini(mode='rgb', room_gate=True, posed=True, sweep_depth=True)
    images = torch.rand(1, 2, 3, 96, 128)
    intrinsics = torch.tensor([[64.0, 0.0, 63.5], [0.0, 64.0, 47.5], [0.0, 0.0, 1.0]]).expand(1, 2, 3, 3)
    poses = torch.eye(4).repeat(1, 2, 1, 1)
    poses[0, 1, 0, 3] = 0.1
    _, _, embeddings, _, room_logits, _ = model.forward_training(
        images, intrinsics=intrinsics, world_from_camera=poses, instance_gradient=instance_gradient)
    (embeddings.square().mean() + room_logits.square().mean()).backward()
    norm = lambda params: sum(float(p.grad.norm()) for p in params if p.grad is not None)  # noqa: E731
    return norm(model.reconstruction_parameters()), norm(model.instance_parameters())


def test_decoupled_instance_losses_leave_the_depth_path_alone():
    reconstruction, instance = instance_loss_gradients(instance_gradient=False)
    assert reconstruction == 0.0
    assert instance > 0.0


def test_coupled_instance_losses_reach_the_depth_path():
    reconstruction, instance = instance_loss_gradients(instance_gradient=True)
    assert reconstruction > 0.0
    assert instance > 0.0
