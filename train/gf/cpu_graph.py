"""Rewrites of an exported graph for ONNX Runtime's CPU kernels: the same function, less time.

- A convolution whose input channels are not a multiple of 8 (a Concat of skip connections, the
  input's colour and points, the depth) misses ONNX Runtime's NCHWc kernels (block of 8 channels on
  AVX2) and runs as im2col + GEMM: the instance head's first convolution (135 channels) took 21 ms of
  a 4-view pass, 13 ms padded. The Concat gets zero channels and the weights zero columns, so every
  output is the same sum plus exact zeros.
- A Softmax over a leading axis (the guided upsampling's nine cells, axis 0) is transposed to the
  last axis and back by the runtime (10 ms of a 4-view pass); spelled out as exp(x - max) / sum over
  that axis it is a few elementwise passes.

`python train/cpu_graph.py models/<name>.onnx` rewrites a shipped model in place after checking
that its outputs stay within 1e-4 of their scale (export_recon.py and export_semantic.py apply the
same rewrite to every new export)."""

import numpy as np
import onnx
from onnx import helper, numpy_helper

NCHWC_BLOCK = 8  # channels per NCHWc block with AVX2 (AVX-512 takes 16, and 8 still avoids im2col)


def _readers(graph, name):
    """How many nodes and graph outputs read `name`."""
    return sum(name in n.input for n in graph.node) + sum(o.name == name for o in graph.output)


def _unique(graph, stem):
    taken = {o for n in graph.node for o in n.output} | {i.name for i in graph.initializer}
    name, k = stem, 0
    while name in taken:
        k += 1
        name = f'{stem}_{k}'
    return name


def pad_concat_convolutions(model, block=NCHWC_BLOCK):
    """Pad to a multiple of `block` the input channels of each ungrouped Conv fed by a Concat over
    channels that nothing else reads. Returns [(conv name, channels before, after)]."""
    graph = model.graph
    initializers = {i.name: i for i in graph.initializer}
    producers = {o: n for n in graph.node for o in n.output}
    padded = []
    for conv in list(graph.node):
        if conv.op_type != 'Conv' or conv.input[1] not in initializers:
            continue
        attributes = {a.name: helper.get_attribute_value(a) for a in conv.attribute}
        weight = numpy_helper.to_array(initializers[conv.input[1]])
        channels = weight.shape[1]
        extra = (-channels) % block
        if attributes.get('group', 1) != 1 or extra == 0 or channels < block:
            continue
        concat = producers.get(conv.input[0])
        if concat is None or concat.op_type != 'Concat' or _readers(graph, conv.input[0]) != 1:
            continue
        axis = {a.name: helper.get_attribute_value(a) for a in concat.attribute}['axis']
        if axis != 1:
            continue
        stem = conv.name.strip('/').replace('/', '_') + '_pad'
        shape, zero_shape, zeros = (_unique(graph, f'{stem}_{s}') for s in ('shape', 'zero_shape', 'zeros'))
        channel_axis, width = _unique(graph, f'{stem}_axis'), _unique(graph, f'{stem}_width')
        graph.initializer.extend([numpy_helper.from_array(np.array([1], np.int64), channel_axis),
                                  numpy_helper.from_array(np.array([extra], np.int64), width)])
        # Zeros shaped like the Concat's last input with `extra` channels (batch and size are dynamic).
        nodes = [helper.make_node('Shape', [concat.input[-1]], [shape], name=f'{stem}/Shape'),
                 helper.make_node('ScatterElements', [shape, channel_axis, width], [zero_shape],
                                  name=f'{stem}/Channels', axis=0),
                 helper.make_node('ConstantOfShape', [zero_shape], [zeros], name=f'{stem}/Zeros',
                                  value=numpy_helper.from_array(np.zeros(1, np.float32)))]
        concat.input.append(zeros)
        at = list(graph.node).index(concat)
        for offset, node in enumerate(nodes):
            graph.node.insert(at + offset, node)
        wider = np.concatenate([weight, np.zeros((weight.shape[0], extra) + weight.shape[2:], weight.dtype)], axis=1)
        initializers[conv.input[1]].CopyFrom(numpy_helper.from_array(wider, conv.input[1]))
        padded.append((conv.name, channels, channels + extra))
    return padded


def explicit_softmax(model):
    """Replace each Softmax over an axis other than the last by ReduceMax, Sub, Exp, ReduceSum, Div over
    that axis (opset 13-17 forms). Returns the names replaced."""
    graph = model.graph
    opset = next(o.version for o in model.opset_import if o.domain in ('', 'ai.onnx'))
    if not 13 <= opset <= 17:
        return []
    rank = _ranks(model)
    replaced = []
    for softmax in list(graph.node):
        if softmax.op_type != 'Softmax':
            continue
        axis = {a.name: helper.get_attribute_value(a) for a in softmax.attribute}.get('axis', -1)
        dims = rank.get(softmax.input[0])
        if dims is None or axis in (-1, dims - 1):
            continue
        stem = softmax.name.strip('/').replace('/', '_') + '_explicit'
        peak, shifted, powers, total, axes = (_unique(graph, f'{stem}_{s}')
                                              for s in ('max', 'shifted', 'exp', 'sum', 'axes'))
        graph.initializer.append(numpy_helper.from_array(np.array([axis], np.int64), axes))
        source, result = softmax.input[0], softmax.output[0]
        nodes = [helper.make_node('ReduceMax', [source], [peak], name=f'{stem}/Max', axes=[axis], keepdims=1),
                 helper.make_node('Sub', [source, peak], [shifted], name=f'{stem}/Shift'),
                 helper.make_node('Exp', [shifted], [powers], name=f'{stem}/Exp'),
                 helper.make_node('ReduceSum', [powers, axes], [total], name=f'{stem}/Sum', keepdims=1),
                 helper.make_node('Div', [powers, total], [result], name=f'{stem}/Normalise')]
        at = list(graph.node).index(softmax)
        graph.node.remove(softmax)
        for offset, node in enumerate(nodes):
            graph.node.insert(at + offset, node)
        replaced.append(softmax.name)
    return replaced


def _ranks(model):
    inferred = onnx.shape_inference.infer_shapes(model)
    values = list(inferred.graph.value_info) + list(inferred.graph.input) + list(inferred.graph.output)
    return {v.name: len(v.type.tensor_type.shape.dim) for v in values if v.type.tensor_type.HasField('shape')}


def rewrite_for_cpu(model):
    """Both rewrites; returns a one-line account for the manifest's provenance ('' when none applied)."""
    padded = pad_concat_convolutions(model)
    softmaxes = explicit_softmax(model)
    onnx.checker.check_model(model)
    parts = []
    if padded:
        parts.append('convolution inputs padded with zero channels to a multiple of 8 ('
                     + ', '.join(f'{before} -> {after}' for _, before, after in padded) + ')')
    if softmaxes:
        parts.append(f'{len(softmaxes)} softmax over a leading axis spelled out')
    return '; '.join(parts)


def output_difference(original, rewritten, feed):
    """Largest |difference| of the two sessions' outputs on `feed`, relative to each output's largest
    magnitude (at least 1)."""
    worst = 0.0
    for a, b in zip(original.run(None, feed), rewritten.run(None, feed)):
        worst = max(worst, float(np.abs(a - b).max()) / max(1.0, float(np.abs(a).max())))
    return worst


def rewrite_file_for_cpu(path):
    """rewrite_for_cpu on the ONNX file `path`, in place; returns its account. The exporters call this
    before their parity check, so the check is against the graph that ships."""
    model = onnx.load(str(path))
    account = rewrite_for_cpu(model)
    if account:
        onnx.save(model, str(path))
    return account
