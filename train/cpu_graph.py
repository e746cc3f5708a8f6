"""Rewrite shipped models in place for ONNX Runtime's CPU kernels (gf.cpu_graph: convolution inputs
padded to 8 channels, softmax over a leading axis spelled out), after checking that the outputs stay
within 1e-4 of their scale on random inputs (2 and 4 views), and add the rewrite to each manifest's
provenance. New exports get the same rewrite from export_recon.py / export_semantic.py.

  train/.venv/bin/python train/cpu_graph.py models/groupforward-mini-rgbd.onnx models/semantic-mini.onnx
"""

import argparse
import re
import sys
from pathlib import Path

import onnx
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gf.cpu_graph import output_difference, rewrite_for_cpu  # noqa: E402
from gf.model import cpu_session, example_inputs  # noqa: E402
from gf.recover import PARITY  # noqa: E402  (the exporters' and the recovery's bound)


def random_feed(session, views, generator):
    """Inputs for `session`: the reconstruction contract's (example_inputs) or a single image."""
    names = [i.name for i in session.get_inputs()]
    if names == ['image']:
        return {'image': torch.rand(1, 3, 96, 128, generator=generator).numpy()}
    return {k: v.numpy() for k, v in example_inputs(names, views, generator).items()}


def note_in_manifest(manifest, account, worst):
    text = manifest.read_text()
    note = f'graph rewritten for the CPU runtime ({account}; outputs within {worst:.1e} of their scale)'
    if 'graph rewritten for the CPU runtime' in text:
        return
    text = re.sub(r'^(provenance = ".*)"$', lambda m: f'{m.group(1)}; {note}"', text, count=1, flags=re.M)
    manifest.write_text(text)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('models', nargs='+', type=Path)
    args = parser.parse_args()
    for path in args.models:
        model = onnx.load(str(path))
        account = rewrite_for_cpu(model)
        if not account:
            print(f'{path}: nothing to rewrite')
            continue
        rewritten = model.SerializeToString()
        original, faster = cpu_session(path), cpu_session(rewritten)
        generator = torch.Generator().manual_seed(0)
        worst = max(output_difference(original, faster, random_feed(original, views, generator)) for views in (2, 4))
        if worst > PARITY:
            sys.exit(f'{path}: the rewritten graph differs by {worst:.1e} of the outputs\' scale; left unchanged')
        path.write_bytes(rewritten)
        note_in_manifest(path.with_suffix('.toml'), account, worst)
        print(f'{path}: {account}; outputs within {worst:.1e}')


if __name__ == '__main__':
    main()
