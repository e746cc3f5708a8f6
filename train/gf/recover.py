"""A checkpoint recovered from an exported GroupForward-mini (models/<name>.onnx), for a shipped
model whose training run is gone: to score it with an inference-time change (eval_recon.py
`--guided`), export it again with one (export_recon.py) or fine-tune it (train_recon.py --init).

The legacy exporter keeps most parameters as initializers named `model.<parameter>`, but renames the
GroupNorm affines (`onnx::Mul_*` / `onnx::Add_*`, shaped [C,1,1]) and the Linear weights
(`onnx::MatMul_*`, transposed). Those are matched to the architecture's missing parameters in
order, checked by shape, and the whole recovery by output parity with the ONNX file."""

import re

import numpy as np
import onnx
import torch
from onnx import numpy_helper

from .model import GroupForwardMini, cpu_session, example_inputs, onnx_parity

PARITY = 1e-4  # of each output's largest magnitude (at least 1), as export_recon.py checks


class RecoveryError(Exception):
    pass


def _number(name):
    return int(re.findall(r'\d+$', name)[0])


def recovered_model(path, mode, guided=None):
    """GroupForwardMini with the weights of the ONNX file `path` (its room shift included), in eval mode.
    The exporter folds the guided upsampling's widths into constants: a model exported with it is
    recovered with `guided` = (σ_points, σ_colour), which the output parity then checks."""
    initializers = _initializers(path)
    named = {name[len('model.'):]: value for name, value in initializers.items() if name.startswith('model.')}
    # Only the renamed initializers are missing, and none of them decides the architecture.
    model = GroupForwardMini.for_parameter_names(
        {name: torch.from_numpy(value.copy()) for name, value in named.items()}, mode)
    state = recovered_state(path, initializers, named, model.state_dict())
    if guided is not None and 'instance_guide_sigmas' not in state:
        model.enable_guided_upsampling(*guided)
        state['instance_guide_sigmas'] = model.instance_guide_sigmas
    model.load_state_dict(state)
    model.eval()
    check_parity(model, path)
    return model


def recovered_semantic(path):
    """SemanticMini with the weights of the exported semantic model `path`, in eval mode. Its
    `logit_scale` is a training-only parameter the export drops: it keeps its initial value, for
    the caller to fit (train_semantic.py --init)."""
    from .semantic import SemanticMini
    initializers = _initializers(path)
    model = SemanticMini()
    expected = model.state_dict()
    named = {name: value for name, value in initializers.items() if name in expected}
    state = recovered_state(path, initializers, named, expected, training_only=('logit_scale',))
    state['logit_scale'] = expected['logit_scale']
    model.load_state_dict(state)
    model.eval()
    feed = {'image': torch.rand(1, 3, 96, 128, generator=torch.Generator().manual_seed(0))}
    worst = onnx_parity(model, cpu_session(path), feed, outputs=('features',))
    if worst > PARITY:
        raise RecoveryError(f'{path}: the recovered outputs differ by {worst:.1e} of their scale')
    return model


def _initializers(path):
    graph = onnx.load(str(path)).graph
    return {t.name: numpy_helper.to_array(t) for t in graph.initializer}


def recovered_state(path, initializers, named, expected, training_only=()):
    """A state dict for the parameters `expected`: those the exporter kept under their own names
    (`named`, zero input-channel padding cut), and the renamed GroupNorm affines and Linear
    weights matched in order to the missing ones, checked by shape."""
    state = {name: _without_padding(name, torch.from_numpy(value.copy()), expected.get(name))
             for name, value in named.items()}
    missing = [k for k in expected if k not in state and k not in training_only]
    renamed = sorted((k for k in initializers if k.startswith('onnx::')), key=_number)
    matrices = [k for k in renamed if k.startswith('onnx::MatMul')]
    # Scalar constants the exporter also renames (`onnx::Pow_*` of the guided upsampling) are not parameters.
    affines = [k for k in renamed if k.startswith(('onnx::Mul', 'onnx::Add'))]
    vectors = [k for k in missing if expected[k].dim() == 1]
    linears = [k for k in missing if expected[k].dim() == 2]
    if len(vectors) != len(affines) or len(linears) != len(matrices) or len(vectors) + len(linears) != len(missing):
        raise RecoveryError(f'{path}: {len(missing)} parameters to recover from {len(renamed)} renamed initializers')
    for name, source, value in [(k, s, initializers[s].reshape(-1)) for k, s in zip(vectors, affines)] + \
            [(k, s, initializers[s].T) for k, s in zip(linears, matrices)]:
        if value.shape != expected[name].shape:
            raise RecoveryError(f'{path}: {source} {value.shape} does not fit {name} {tuple(expected[name].shape)}')
        state[name] = torch.from_numpy(np.array(value, copy=True))
    return state


def _without_padding(name, value, expected):
    """A convolution weight whose input channels gf.cpu_graph padded with zeros, cut back to the
    architecture's; any other value as it is."""
    if expected is None or value.dim() != 4 or value.shape == expected.shape:
        return value
    channels = expected.shape[1]
    if (value.shape[0], *value.shape[2:]) != (expected.shape[0], *expected.shape[2:]) \
            or value.shape[1] < channels or value[:, channels:].abs().max() != 0:
        raise RecoveryError(f'{name}: {tuple(value.shape)} is not {tuple(expected.shape)} padded with zero channels')
    return value[:, :channels].contiguous()


def model_from_file(path, mode, guided=None):
    """GroupForwardMini with the weights of a train_recon.py checkpoint (.pt) or of an exported model
    (.onnx, recovered as above)."""
    if str(path).endswith('.onnx'):
        return recovered_model(path, mode, guided)
    return GroupForwardMini.from_state_dict(torch.load(path, map_location='cpu'), mode)


def check_parity(model, path):
    """Raise RecoveryError unless `model` reproduces the ONNX file's outputs on random inputs."""
    session = cpu_session(path)
    feed = example_inputs(model.input_names(), 2, torch.Generator().manual_seed(0))
    worst = onnx_parity(model, session, feed)
    if worst > PARITY:
        raise RecoveryError(f'{path}: the recovered outputs differ by {worst:.1e} of their scale')
