"""Export a trained Semantic-mini to ONNX (legacy exporter, opset 17), check parity with PyTorch
through onnxruntime (max abs diff <= 1e-4), and write its manifest (models/<name>.toml) with the val
metrics of the windows held out from checkpoint selection.

  train/.venv/bin/python train/export_semantic.py --model train/runs/semantic/model.pt \\
      --summary train/runs/semantic/summary.json --report train/runs/semantic/report.json --name semantic-mini
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gf.cpu_graph import rewrite_file_for_cpu  # noqa: E402
from export_recon import run_origin  # noqa: E402
from gf.model import parameter_count  # noqa: E402
from gf.semantic import FEATURE_DIM, SemanticMini  # noqa: E402

MODELS = Path(__file__).resolve().parents[1] / 'models'


def how_trained(run_args):
    """(where the weights came from, what picked the checkpoint) of a train_semantic.py run's args: a run
    continued from an exported model (--init) names that model's training first, so this run's steps are not
    read as the whole; and the loss when it is not the recipe's."""
    origin = run_origin(run_args)
    if origin != 'trained from scratch':
        origin += '; this run'
    if run_args.get('instance_weight'):
        origin += f" with the instances' pooled prototypes in the loss (weight {run_args['instance_weight']:g})"
    picked_by = {'miou': 'mIoU', 'instance_accuracy': 'instances named'}[run_args.get('select', 'miou')]
    return origin, picked_by


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--model', required=True)
    parser.add_argument('--summary', required=True)
    parser.add_argument('--report', required=True, help='train_semantic.py --report output on held-out val windows')
    parser.add_argument('--name', required=True)
    args = parser.parse_args()
    height, width = 96, 128
    model = SemanticMini(height, width)
    model.load_state_dict(torch.load(args.model))
    model.eval()
    summary = json.loads(Path(args.summary).read_text())
    report = json.loads(Path(args.report).read_text())
    generator = torch.Generator().manual_seed(0)
    image = torch.rand(1, 3, height, width, generator=generator)
    onnx_path = MODELS / f'{args.name}.onnx'
    torch.onnx.export(model, (image,), onnx_path, input_names=['image'], output_names=['features'],
                      opset_version=17, dynamo=False)
    rewrite = rewrite_file_for_cpu(onnx_path)
    session = ort.InferenceSession(str(onnx_path), providers=['CPUExecutionProvider'])
    worst = 0.0
    for _ in range(3):
        image = torch.rand(1, 3, height, width, generator=generator)
        with torch.no_grad():
            expected = model(image).numpy()
        (got,) = session.run(['features'], {'image': image.numpy()})
        worst = max(worst, float(np.abs(expected - got).max()))
    assert worst <= 1e-4, f'ONNX parity {worst} > 1e-4'
    best = summary['best']
    size = onnx_path.stat().st_size
    # Runs before these fields: no effects, on the CPU.
    drawn = summary.get('train_effects')
    drawn = [drawn] if isinstance(drawn, str) else drawn
    effects = f'; sim effects {" + ".join(drawn)} (sim dataset --effects)' if drawn and drawn != ['clean'] else ''
    device = summary.get('device', 'cpu')
    trained_on = (f"on {summary['threads']} CPU thread(s)" if device == 'cpu'
                  else f"on a lent GPU ({device}, {summary['threads']} CPU threads for the data)")
    origin, picked_by = how_trained(summary.get('args', {}))
    rewritten = f'; graph rewritten for the CPU runtime ({rewrite})' if rewrite else ''
    manifest = f'''# Semantic-mini (the LSeg role), trained here on the simulator by train/train_semantic.py. Not a
# pretrained model: {parameter_count(model) / 1e6:.2f} M parameters, 16 object classes of small synthetic rooms
# plus `other`; features live in the all-MiniLM-L6-v2 text space (cosine to a phrase's embedding).
name = "{args.name}"
kind = "semantic"
file = "{args.name}.onnx"
input_height = {height}
input_width = {width}
embedding_dim = {FEATURE_DIM}
provenance = "{origin} on groupforward-sim train split ({summary['train_windows']} windows x 4 views, 128x96{effects}) against the int8 all-MiniLM-L6-v2 embeddings of class names and descriptions; checkpoint of step {best['step']} ({best['minutes']:.0f} min) of a {summary['steps']}-step, {summary['minutes']:.0f}-min run {trained_on}, picked by {picked_by} on {best['windows']} val windows; benchmarks below on {report['windows']} other val windows; ONNX parity {worst:.1e}{rewritten}; {size / 1e6:.1f} MB"
license = "Apache-2.0"

[normalization]
image_mean = [0.0, 0.0, 0.0]
image_std = [1.0, 1.0, 1.0]

[[inputs]]
name = "image"
shape = [1, 3, {height}, {width}]

[[outputs]]
name = "features"
shape = [1, {FEATURE_DIM}, {height // 2}, {width // 2}]

[benchmarks]
# train/train_semantic.py --report on the val windows held out from checkpoint selection.
'''
    for key in ('pixel_accuracy', 'miou', 'synonym_pixel_accuracy', 'synonym_miou', 'instance_accuracy',
                'instances', 'windows'):
        manifest += f'val_{key} = {float(report[key]):.4f}\n'
    manifest += f'size_mb = {size / 1e6:.2f}\nparameters_m = {parameter_count(model) / 1e6:.2f}\n'
    (MODELS / f'{args.name}.toml').write_text(manifest)
    print(f'wrote {onnx_path} ({size / 1e6:.1f} MB) and its manifest; parity {worst:.2e}')


if __name__ == '__main__':
    main()
