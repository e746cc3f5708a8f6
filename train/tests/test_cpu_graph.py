"""gf.cpu_graph: the exported graph rewritten for ONNX Runtime's CPU kernels computes the same
outputs, and an exported model rewritten that way is still recovered (`make train-test`)."""

import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from onnx import helper, numpy_helper

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gf.cpu_graph import explicit_softmax, output_difference, pad_concat_convolutions, rewrite_for_cpu  # noqa: E402
from gf.model import GroupForwardMini, cpu_session  # noqa: E402
from gf.recover import RecoveryError, recovered_model  # noqa: E402
from test_guided_upsampling import export, trained_like  # noqa: E402


def concat_conv_softmax(channels=(5, 6), out=4, softmax_axis=0):
    """x [N,5,H,W] and y [N,6,H,W] concatenated into an 11-channel 3×3 convolution, then a softmax over
    `softmax_axis`; a second output reads the concatenation itself (so it must keep 11 channels)."""
    rng = np.random.default_rng(0)
    weight = rng.standard_normal((out, sum(channels), 3, 3)).astype(np.float32)
    inputs = [helper.make_tensor_value_info(n, onnx.TensorProto.FLOAT, ['N', c, 'H', 'W'])
              for n, c in zip('xy', channels)]
    nodes = [helper.make_node('Concat', ['x', 'y'], ['cat'], axis=1),
             helper.make_node('Conv', ['cat', 'w'], ['conv'], pads=[1, 1, 1, 1]),
             helper.make_node('Softmax', ['conv'], ['probabilities'], axis=softmax_axis)]
    graph = helper.make_graph(nodes, 'g', inputs,
                              [helper.make_tensor_value_info('probabilities', onnx.TensorProto.FLOAT, ['N', out, 'H', 'W'])],
                              [numpy_helper.from_array(weight, 'w')])
    # IR version 8, as the legacy exporter writes (onnxruntime 1.31 reads up to 13).
    return helper.make_model(graph, opset_imports=[helper.make_opsetid('', 17)], ir_version=8)


def feed(batch=3, height=5, width=7):
    rng = np.random.default_rng(1)
    return {'x': rng.standard_normal((batch, 5, height, width)).astype(np.float32) * 4,
            'y': rng.standard_normal((batch, 6, height, width)).astype(np.float32) * 4}


def test_a_concatenated_input_is_padded_to_eight_channels_and_the_outputs_stay():
    model = concat_conv_softmax()
    original = cpu_session(model.SerializeToString())
    assert rewrite_for_cpu(model).startswith('convolution inputs padded with zero channels to a multiple of 8 (11 -> 16)')
    weights = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    assert weights['w'].shape == (4, 16, 3, 3) and not weights['w'][:, 11:].any()
    assert 'Softmax' not in [n.op_type for n in model.graph.node]
    rewritten = cpu_session(model.SerializeToString())
    for shape in ((3, 5, 7), (1, 1, 1), (2, 9, 4)):  # batch, height and width stay dynamic
        assert output_difference(original, rewritten, feed(*shape)) < 1e-5  # float32 sums in another order


def test_a_softmax_over_a_leading_axis_survives_huge_logits_and_the_last_axis_is_left_alone():
    model = concat_conv_softmax(softmax_axis=0)
    explicit_softmax(model)
    session = cpu_session(model.SerializeToString())
    inputs = {k: v * 1e4 for k, v in feed().items()}  # exp would overflow without the max
    (probabilities,) = session.run(None, inputs)
    assert np.isfinite(probabilities).all()
    assert np.allclose(probabilities.sum(0), 1.0, atol=1e-5)
    last = concat_conv_softmax(softmax_axis=-1)
    assert explicit_softmax(last) == []


def test_a_concatenation_read_twice_or_a_grouped_convolution_is_left_as_it_is():
    model = concat_conv_softmax()
    model.graph.output.append(helper.make_tensor_value_info('cat', onnx.TensorProto.FLOAT, ['N', 11, 'H', 'W']))
    assert pad_concat_convolutions(model) == []
    grouped = concat_conv_softmax(channels=(5, 7), out=6)
    weight = next(i for i in grouped.graph.initializer if i.name == 'w')
    weight.CopyFrom(numpy_helper.from_array(np.ones((6, 6, 3, 3), np.float32), 'w'))
    next(n for n in grouped.graph.node if n.op_type == 'Conv').attribute.append(helper.make_attribute('group', 2))
    assert pad_concat_convolutions(grouped) == []


def test_a_rewritten_export_is_recovered_with_its_weights_and_zero_padding_is_told_apart(tmp_path):
    torch.manual_seed(1)
    model = trained_like(GroupForwardMini(mode='rgbd', room_gate=True))
    export(model, tmp_path / 'model.onnx')
    graph = onnx.load(str(tmp_path / 'model.onnx'))
    assert 'padded' in rewrite_for_cpu(graph)
    onnx.save(graph, str(tmp_path / 'model.onnx'))
    recovered = recovered_model(tmp_path / 'model.onnx', 'rgbd')
    for name, value in model.state_dict().items():
        assert torch.equal(recovered.state_dict()[name], value), name
    # Padding that is not zeros is a different function: refused, not cut.
    padded = next(i for i in graph.graph.initializer
                  if numpy_helper.to_array(i).ndim == 4 and numpy_helper.to_array(i).shape[1] == 136)
    weight = numpy_helper.to_array(padded).copy()
    weight[:, -1] = 1.0
    padded.CopyFrom(numpy_helper.from_array(weight, padded.name))
    onnx.save(graph, str(tmp_path / 'model.onnx'))
    with pytest.raises(RecoveryError):
        recovered_model(tmp_path / 'model.onnx', 'rgbd')
