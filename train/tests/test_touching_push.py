"""The touching-pairs hard negatives (gf.losses.touching_pairs, touching_push)."""
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gf.losses import MARGIN, direct_losses, touching_pairs, touching_push  # noqa: E402


def test_only_neighbouring_objects_of_one_class_are_touching_pairs():
    # One view, 3 cabinets in a row (1, 2 touch; 3 apart), a chair (4) touching cabinet 3, the room 0.
    instance = torch.tensor([[[1, 1, 2, 2, 0, 3, 4],
                              [1, 1, 2, 2, 0, 3, 4]]])
    klass = torch.tensor([[[5, 5, 5, 5, 0, 5, 7],
                           [5, 5, 5, 5, 0, 5, 7]]])
    assert touching_pairs(instance, klass).tolist() == [[1, 2]]


def test_a_window_without_touching_pairs_adds_nothing_and_stays_finite():
    instance = torch.tensor([[[1, 0, 2]]])
    klass = torch.tensor([[[3, 0, 3]]])
    pairs = touching_pairs(instance, klass)
    assert pairs.shape == (0, 2)
    centroids = torch.nn.functional.normalize(torch.randn(3, 8), dim=1)
    assert touching_push(centroids, torch.tensor([0, 1, 2]), pairs).item() == 0.0


def test_touching_pairs_with_equal_embeddings_pay_the_whole_margin():
    # Two touching cabinets embedded alike: the plain push pays the hinge over all 6 ordered pairs of
    # 3 instances, the touching term pays the margin for the one pair.
    embeddings = torch.zeros(1, 1, 2, 1, 6)
    embeddings[0, 0, 0, 0, :4] = 1.0  # instances 1 and 2 at (1, 0)
    embeddings[0, 0, 1, 0, 4:] = 1.0  # the room at (0, 1)
    instance = torch.tensor([[[[1, 1, 2, 2, 0, 0]]]])
    klass = torch.tensor([[[[5, 5, 5, 5, 0, 0]]]])
    generator = torch.Generator().manual_seed(0)
    _, plain = direct_losses(embeddings, instance, samples=512, generator=generator)
    generator = torch.Generator().manual_seed(0)
    _, hard = direct_losses(embeddings, instance, samples=512, generator=generator, klass=klass, touching_weight=1.0)
    assert abs((hard - plain).item() - MARGIN) < 1e-5
