"""Shift the room gate's logit of an exported GroupForward-mini (models/<name>.onnx) by a constant, in
place, and rewrite its manifest's provenance and benchmarks: the same calibration as
`export_recon.py --room-bias` (GroupForwardMini.shift_room_logit), for a shipped model whose
checkpoint is gone. Choose the shift on the selection windows first, and score the held-out ones
with it (eval_recon.py on a calibrated copy), e.g.

  git show 60f827b:models/groupforward-mini-rgbd.onnx > /tmp/unshifted.onnx
  T="train/.venv/bin/python train"; M="--name groupforward-mini-rgbd --model /tmp/unshifted.onnx"
  $T/calibrate_recon.py $M --room-bias 2 --out /tmp/b2.onnx
  $T/eval_recon.py --model /tmp/b2.onnx --val train/data/val --first 76                  # selection
  $T/eval_recon.py --model /tmp/b2.onnx --val train/data/val --windows 76 > /tmp/report.json
  $T/calibrate_recon.py $M --room-bias 2 --report /tmp/report.json                      # ships it
"""

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_recon import OnnxModel  # noqa: E402
from export_recon import MODELS, benchmarks_section, room_shift_note  # noqa: E402
from gf.model import room_logit_bias_name  # noqa: E402


def shifted(model, bias):
    """A copy of the ONNX `model` with its room logit shifted by `bias`."""
    model = onnx.ModelProto.FromString(model.SerializeToString())
    names = {t.name: i for i, t in enumerate(model.graph.initializer)}
    if 'instance_room_vector' not in names:
        raise SystemExit('this model has no room gate to calibrate')
    name = room_logit_bias_name(sharp_gate=room_logit_bias_name(True) in names)
    tensor = model.graph.initializer[names[name]]
    values = numpy_helper.to_array(tensor).copy()
    values[-1] += bias
    tensor.CopyFrom(numpy_helper.from_array(values, name))
    return model


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--name', required=True, help='models/<name>.onnx and its manifest')
    parser.add_argument('--model', help='the exported model to shift (default models/<name>.onnx); a sweep starts '
                                        'from the unshifted file, e.g. one taken out of git')
    parser.add_argument('--room-bias', type=float, required=True)
    parser.add_argument('--out', help='write the calibrated ONNX here instead (to score it); the manifest is untouched')
    parser.add_argument('--report', help='eval_recon.py JSON of the calibrated model on the held-out windows')
    args = parser.parse_args()
    if not args.out and not args.report:
        parser.error('in place needs --report (the manifest\'s benchmarks must describe the calibrated model)')
    path = MODELS / f'{args.name}.onnx'
    original = onnx.load(args.model or path)
    calibrated = shifted(original, args.room_bias)
    # Only the embeddings may change.
    generator = np.random.default_rng(0)
    images = torch.from_numpy(generator.random((1, 2, 3, 96, 128), np.float32))
    points = torch.from_numpy((generator.standard_normal((1, 2, 3, 96, 128)) * 0.5).astype(np.float32))
    before, after = (OnnxModel(m.SerializeToString())(images, points) for m in (original, calibrated))
    assert torch.equal(before[0], after[0]) and torch.equal(before[1], after[1])
    assert not torch.equal(before[2], after[2])
    out = Path(args.out) if args.out else path
    onnx.save(calibrated, out)
    if args.out:
        print(f'wrote {out}')
        return
    manifest_path = MODELS / f'{args.name}.toml'
    manifest = manifest_path.read_text()
    clause = f'; {room_shift_note(args.room_bias)}'
    # The shift describes this run from the unshifted file: any earlier one's words go.
    earlier = re.escape(f'; {room_shift_note(0.0)}').replace(r'\+0', r'[+-][0-9.e+-]+')
    manifest = re.sub(earlier, '', manifest)
    manifest = re.sub(r'^(provenance = ".*?)(; depth and)', lambda m: m.group(1) + clause + m.group(2), manifest,
                      count=1, flags=re.M)
    assert clause in manifest, 'the provenance line has an unexpected shape'
    parameters = float(re.search(r'^parameters_m = ([0-9.]+)', manifest, re.M).group(1)) * 1e6
    report = json.loads(Path(args.report).read_text())
    manifest = manifest[:manifest.index('\n[benchmarks]')] + benchmarks_section(
        report, out.stat().st_size, parameters)
    manifest_path.write_text(manifest)
    print(f'calibrated {out} by {args.room_bias:+g} and rewrote {manifest_path.name}')


if __name__ == '__main__':
    main()
