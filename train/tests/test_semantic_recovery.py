"""gf.recover.recovered_semantic: an exported Semantic-mini (rewritten for the CPU runtime as
export_semantic.py does) comes back with every trained weight, so train_semantic.py --init continues
the shipped model rather than a copy that merely looks alike (`make train-test`)."""

import sys
from pathlib import Path

import onnx
import pytest
import torch
from onnx import numpy_helper

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gf.cpu_graph import rewrite_for_cpu  # noqa: E402
from gf.recover import RecoveryError, recovered_semantic  # noqa: E402
from gf.semantic import SemanticMini  # noqa: E402
from test_guided_upsampling import trained_like  # noqa: E402


def exported(model, path):
    model.eval()
    torch.onnx.export(model, (torch.rand(1, 3, 96, 128),), path, input_names=['image'],
                      output_names=['features'], opset_version=17, dynamo=False)
    graph = onnx.load(str(path))
    assert 'padded' in rewrite_for_cpu(graph)
    onnx.save(graph, str(path))
    return graph


def test_an_exported_semantic_model_is_recovered_with_every_weight_but_the_training_scale(tmp_path):
    torch.manual_seed(2)
    model = trained_like(SemanticMini())
    graph = exported(model, tmp_path / 'semantic.onnx')
    recovered = recovered_semantic(tmp_path / 'semantic.onnx')
    for name, value in model.state_dict().items():
        if name != 'logit_scale':
            assert torch.equal(recovered.state_dict()[name], value), name
    # A weight the graph does not hold as the architecture's is refused, not guessed.
    head = next(i for i in graph.graph.initializer if i.name == 'head.weight')
    head.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(head)[:100].copy(), 'head.weight'))
    onnx.save(graph, str(tmp_path / 'semantic.onnx'))
    with pytest.raises(RecoveryError):
        recovered_semantic(tmp_path / 'semantic.onnx')


def test_a_semantic_export_missing_a_renamed_affine_is_refused(tmp_path):
    graph = exported(trained_like(SemanticMini()), tmp_path / 'semantic.onnx')
    recovered_semantic(tmp_path / 'semantic.onnx')
    affine = next(i for i in graph.graph.initializer if i.name.startswith('onnx::Mul'))
    graph.graph.initializer.remove(affine)
    onnx.save(graph, str(tmp_path / 'semantic.onnx'))
    with pytest.raises(RecoveryError):
        recovered_semantic(tmp_path / 'semantic.onnx')


def test_the_instance_loss_scores_pooled_prototypes_against_their_instances_classes():
    import train_semantic
    torch.manual_seed(0)
    text = torch.nn.functional.normalize(torch.randn(3, 8), dim=1)
    # Two windows of two 4x4 views; instances 0 (class 0) and 1 (class 2) split each view in halves.
    instance = torch.zeros(4, 4, 4, dtype=torch.int64)
    instance[..., 2:] = 1
    classes = instance * 2
    right = text[classes[:, ::2, ::2]].permute(0, 3, 1, 2)  # features at half resolution
    noisy = right + 0.3 * torch.randn_like(right)
    weights = torch.ones(3)
    good = train_semantic.instance_loss(noisy, instance, classes, text, 20.0, weights, windows=2)
    swapped = train_semantic.instance_loss(noisy, instance, 2 - classes, text, 20.0, weights, windows=2)
    assert torch.isfinite(good) and good < 0.1 < swapped


def test_a_continued_run_names_the_model_it_started_from_its_loss_and_what_picked_it(tmp_path):
    from export_semantic import how_trained
    assert how_trained({}) == ('trained from scratch', 'mIoU')
    start = tmp_path / 'start.onnx'
    start.write_bytes(b'')
    (tmp_path / 'start.toml').write_text('provenance = "trained from scratch on the sim; benchmarks below on 76"\n')
    origin, picked_by = how_trained({'init': str(start), 'instance_weight': 1.0, 'select': 'instance_accuracy'})
    assert origin == ("fine-tuned from an exported model (trained from scratch on the sim); this run with "
                      "the instances' pooled prototypes in the loss (weight 1)")
    assert picked_by == 'instances named'
