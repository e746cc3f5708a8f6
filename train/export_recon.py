"""Export a trained GroupForward-mini to ONNX (legacy exporter, opset 17, dynamic number of views),
check parity with PyTorch through onnxruntime (max abs diff <= 1e-4 of each output's largest
magnitude, at least 1, for V = 2 and 4), and write the manifest the node checks the graph against
(models/<name>.toml). A posed RGB checkpoint (train_recon.py --posed) exports as mode `rgb_posed`,
taking the views' intrinsics and poses as well.

  train/.venv/bin/python train/export_recon.py --model train/runs/rgbd/model.pt --mode rgbd \\
      --summary train/runs/rgbd/summary.json --report train/runs/rgbd/report.json --name groupforward-mini-rgbd

`--guided SIGMA_POINTS,SIGMA_COLOUR` exports with the instance head's joint bilateral upsampling
(GroupForwardMini.enable_guided_upsampling; choose the widths with eval_recon.py --guided). A shipped
model whose training run is gone can be exported again with it from its own weights: `--model
models/<name>.onnx` recovers them (gf.recover, checked by output parity) and keeps the training part
of that model's provenance, so no --summary is needed.

`--input-size 192x144` exports the same weights for a larger input (GroupForwardMini.set_input_size):
the node resamples the camera's views to the manifest's size, so small objects keep more pixels, at
about twice the model's time (train/README.md, "The RGB-D model at 192 x 144").
"""

import argparse
import csv
import json
import re
import sys
from pathlib import Path

import onnxruntime as ort
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gf.cpu_graph import rewrite_file_for_cpu  # noqa: E402
from add_vote_output import MANIFEST_OUTPUT, add_votes  # noqa: E402
from gf.data import POINTS_SCALE  # noqa: E402
from gf.model import example_inputs, onnx_parity, parameter_count  # noqa: E402
from gf.recover import model_from_file  # noqa: E402
from eval_recon import guided_widths  # noqa: E402

MODELS = Path(__file__).resolve().parents[1] / 'models'


def room_shift_note(bias):
    """The provenance's words for a room logit shifted after training (export --room-bias, calibrate_recon)."""
    return f'room logit shifted by {bias:+g} after training (chosen on the selection windows)'


def benchmarks_section(report, size, parameters):
    """The manifest's [benchmarks] table: `report` (eval_recon.py JSON), the ONNX file's size in bytes."""
    section = '\n[benchmarks]\n# train/eval_recon.py on the val windows held out from checkpoint selection.\n'
    for key in ('ari', 'ari_se', 'ari_hdbscan', 'pair_ari', 'pairs', 'clusters', 'instances', 'found', 'in_room',
                'objects', 'oracle_ari', 'abs_rel', 'delta1', 'windows'):
        if report.get(key) is not None:
            section += f'val_{key} = {float(report[key]):.4f}\n'
    return section + f'size_mb = {size / 1e6:.2f}\nparameters_m = {parameters / 1e6:.2f}\n'


def guided_note(sigma_points, sigma_colour, after_training, points):
    """The provenance's words for the instance head's joint bilateral upsampling (guided by colour, and
    by the points where the model takes them)."""
    when = ', switched on after training (chosen on the selection windows)' if after_training else ''
    guide = (f'world XYZ and colour (sigma {sigma_points:g} in the points\' units, {sigma_colour:g})' if points
             else f'colour (sigma {sigma_colour:g})')
    return f'instance head upsampled by joint bilateral upsampling guided by the input\'s {guide}{when}'


def training_provenance(manifest):
    """The part of a shipped manifest's provenance that describes its training: up to the benchmarks."""
    line = re.search(r'^provenance = "(.*)"$', manifest, re.M).group(1)
    return line[:line.index('; benchmarks below')]


class Contract(torch.nn.Module):
    """The model taking exactly its mode's inputs, in the contract's order (the exporter traces positions)."""

    def __init__(self, model, names):
        super().__init__()
        self.model, self.names = model, names

    def forward(self, *tensors):
        return self.model(**dict(zip(self.names, tensors)))


def instance_head_only(train_args):
    """Whether a run trained the instance head alone (curriculum stage 2 only)."""
    return train_args.get('stages', [1, 1, 1])[0::2] == [0, 0]


def earlier_runs(train_args):
    """The runs a run continued (--init), nearest first, as their summaries, and the exported model the
    first of them started from (its .onnx path; None for a random draw)."""
    runs = []
    init = Path(train_args['init']) if train_args.get('init') else None
    while init is not None and init.suffix != '.onnx':
        runs.append(json.loads((init.parent / 'summary.json').read_text()))
        init = Path(runs[-1]['args']['init']) if runs[-1]['args'].get('init') else None
    return runs, init


def trained_guided(train_args):
    """Whether a run trained with the guided upsampling: its own --guided, or carried in from a run it
    continued (a recovered exported model never has it: gf.recover refuses a guided file)."""
    runs, _ = earlier_runs(train_args)
    return any(args.get('guided') for args in [train_args] + [run['args'] for run in runs])


def run_origin(train_args):
    """Where a run's starting weights came from: a random draw, an exported model, or earlier runs (each
    named, so a continuation's steps and minutes are not read as the whole)."""
    runs, exported = earlier_runs(train_args)
    origin = None
    if exported is not None:
        # Recovered weights of an exported model: that model's own training comes first.
        origin = f"fine-tuned from an exported model ({training_provenance(exported.with_suffix('.toml').read_text())})"
    for run in reversed(runs):
        how = ' with --decouple' if run['args'].get('decouple') else ''
        if instance_head_only(run['args']):
            how = ', the instance head alone'
        if origin is None:
            origin = (f"trained from scratch in two runs: {run['steps']} steps ({run['minutes']:.0f} min){how}, "
                      f"then this run from their weights")
        else:
            origin += f"; then {run['steps']} steps ({run['minutes']:.0f} min){how}; then this run from their weights"
    return origin or 'trained from scratch'


def checkpoint_choice(path, summary):
    """(step, minutes, how it was picked) of the exported checkpoint: the run's model.pt (its best on the
    selection windows) or one of its snapshots (snapshot_<step>.pt, its time from the run's log.csv)."""
    match = re.fullmatch(r'snapshot_(\d+)\.pt', Path(path).name)
    if not match:
        best = summary['best']
        return best['step'], best['minutes'], f"picked by ARI on {best['windows']} val windows"
    step = int(match.group(1))
    with open(Path(path).parent / 'log.csv', newline='') as log:
        seconds = next(float(row['seconds']) for row in csv.DictReader(log) if int(row['step']) == step)
    return step, seconds / 60, 'picked among its snapshots by ARI on the val_selection windows'


def machine_note(summary):
    """' (CPU, seed, sessions)' as far as the run's summary records them (runs before 2026-12-06 do not)."""
    parts = [summary.get('cpu')]
    if 'seed' in summary:
        parts.append(f"seed {summary['seed']}")
    if summary.get('sessions', 1) > 1:
        parts.append(f"resumed over {summary['sessions']} sessions")
    parts = [part for part in parts if part]
    return f" ({', '.join(parts)})" if parts else ''


def checkpoint_provenance(args, model, summary, guided):
    """The provenance of a model exported from a training run's checkpoint, up to its benchmarks."""
    step, minutes, picked = checkpoint_choice(args.model, summary)
    losses = ('depth, photometric, direct and rendered instance losses' if summary.get('rendered_losses')
              else 'depth and direct instance losses only')
    train_args = summary['args']
    # The experiments' extra instance terms, so a model trained with them does not read as direct-only.
    if train_args.get('direct_assignment'):
        losses += f"; dice + focal on unrendered assignment probabilities, weight {train_args['direct_assignment']:g}"
    if train_args.get('hard_push'):
        losses += '; push over violating pairs only'
    if instance_head_only(train_args):
        losses += '; only the instance head trained (curriculum stage 2 alone), the depth path as it was'
    elif train_args.get('decouple'):
        losses += '; the instance losses train the instance head alone (decoder and depth by depth losses)'
    if train_args.get('polish'):
        losses += f"; the last {train_args['polish']:.0%} of the budget trained the instance head alone (stage 4)"
    if train_args.get('bf16'):
        losses += '; forward passes in bfloat16 autocast (float32 weights and losses)'
    head = 'instance head: 3D centre votes' if model.centre_votes else 'instance head: plain'
    if model.refine:
        head += ' + full-resolution refinement'
    if train_args.get('vote_weight'):
        room = '; walls and floor vote below the floor' if train_args.get('room_vote') else ''
        target = ("; an object's pixels vote for its whole box's centre"
                  if train_args.get('vote_target') == 'box' else '')
        head += f" (supervised by the centre-vote loss, weight {train_args['vote_weight']:g}{target}{room})"
    if model.room_gate:
        gate = 'full-resolution ' if model.sharp_gate else ''
        weighing = ', per pixel' if train_args.get('gate_per_pixel') else ''
        head += f"; {gate}room gate (wall-or-floor cross-entropy{weighing}, weight {train_args.get('room_gate', 0):g})"
        if args.room_bias:
            head += f'; {room_shift_note(args.room_bias)}'
    if model.posed:
        sweep = (f"; its depth and confidence to the decoder, auxiliary depth loss weight {train_args['sweep_depth']:g}"
                 if model.sweep_depth else '')
        head += f'; plane sweep over the views\' intrinsics and TF poses{sweep}'
    device = summary.get('device', 'cpu')
    origin = run_origin(train_args)
    trained_on = (f"{summary['threads']} CPU thread(s){machine_note(summary)}" if device == 'cpu'
                  else f'a GPU ({device}; the steps are a 2-core CPU budget, see train/ in the README)')
    if guided:
        after_training = bool(args.guided) or not trained_guided(train_args)
        head += f'; {guided_note(*guided, after_training=after_training, points=model.mode == "rgbd")}'
    splits = list(dict.fromkeys(summary.get('train_splits') or ['train']))
    named = f"{' + '.join(splits)} split{'s' if len(splits) > 1 else ''}"
    trained_width, trained_height = summary.get('train_size', (128, 96))
    return (f"{origin} on groupforward-sim {named} ({summary['train_windows']} windows x 4 views, "
            f"{trained_width}x{trained_height}), "
            f"checkpoint of step {step} ({minutes:.0f} min) of a {summary['steps']}-step, "
            f"{summary['minutes']:.0f}-min run on {trained_on}, {picked}; {head}; "
            f"{losses}{'; pseudo instance labels' if train_args.get('pseudo_labels') else ''}")


def input_size(text):
    """`WIDTHxHEIGHT` as (width, height)."""
    try:
        width, height = (int(side) for side in text.lower().split('x'))
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r}: expected WIDTHxHEIGHT, e.g. 192x144') from None
    return width, height


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--model', required=True)
    parser.add_argument('--mode', choices=['rgbd', 'rgb'], default='rgbd')
    parser.add_argument('--summary', help='summary.json of the training run (not for an exported --model)')
    parser.add_argument('--name', required=True)
    parser.add_argument('--room-bias', type=float, default=0.0,
                        help='add this to the room gate\'s logit before export (a calibration chosen on the '
                             'selection windows with eval_recon.py --room-bias; the report must be scored with it)')
    parser.add_argument('--report', required=True,
                        help='eval_recon.py output (JSON) on the val windows held out from checkpoint selection')
    parser.add_argument('--guided', metavar='SIGMA_POINTS,SIGMA_COLOUR', type=guided_widths,
                        help='upsample the instance head by joint bilateral upsampling (eval_recon.py --guided)')
    parser.add_argument('--input-size', metavar='WIDTHxHEIGHT', type=input_size, default=(128, 96),
                        help='the input the exported graph takes (multiples of 16 in the trained 4:3 aspect, '
                             'e.g. 192x144; GroupForwardMini.set_input_size); the report must be scored at it')
    args = parser.parse_args()
    exported = args.model.endswith('.onnx')
    if exported == bool(args.summary):
        parser.error('--summary goes with a checkpoint, and only with one (an exported model has its manifest)')
    if exported:
        # Read before the export below may overwrite the same files.
        earlier = training_provenance(Path(args.model).with_suffix('.toml').read_text())
    # A file exported with the upsampling is recovered with it (its widths are folded into constants).
    model = model_from_file(args.model, args.mode, args.guided if exported else None)
    if args.room_bias:
        model.shift_room_logit(args.room_bias)
    if args.guided:
        model.enable_guided_upsampling(*args.guided)
    # A checkpoint trained with the upsampling (train_recon.py --guided) carries it in its state dict.
    guided = tuple(model.instance_guide_sigmas.tolist()) if model.guided_upsampling else None
    model.eval()
    width, height = args.input_size
    model.set_input_size(height, width)
    generator = torch.Generator().manual_seed(0)
    mode = 'rgb_posed' if model.posed else args.mode
    names = model.input_names()

    def arguments(views):
        return example_inputs(names, views, generator, height, width)

    onnx_path = MODELS / f'{args.name}.onnx'
    dynamic = {name: {1: 'V'} for name in names}
    dynamic.update({'depth': {1: 'V'}, 'gaussians': {1: 'V'}, 'embeddings': {1: 'V'}})
    torch.onnx.export(Contract(model, names), tuple(arguments(2).values()), onnx_path, input_names=names,
                      output_names=['depth', 'gaussians', 'embeddings'], dynamic_axes=dynamic, opset_version=17,
                      dynamo=False)
    rewrite = rewrite_file_for_cpu(onnx_path)
    votes = bool(getattr(model, 'centre_votes', False)) and add_votes(onnx_path)
    session = ort.InferenceSession(str(onnx_path), providers=['CPUExecutionProvider'])
    assert [i.name for i in session.get_inputs()] == names, session.get_inputs()
    worst = max(onnx_parity(model, session, arguments(views)) for views in (2, 4))
    assert worst <= 1e-4, f'ONNX parity {worst} > 1e-4 of the outputs\' scale'
    report = json.loads(Path(args.report).read_text())
    size = onnx_path.stat().st_size
    if exported:
        provenance = earlier
        if args.room_bias:
            provenance += f'; room logit shifted by a further {args.room_bias:+g} (chosen on the selection windows)'
        if guided and 'joint bilateral upsampling' not in provenance:
            provenance += f'; {guided_note(*guided, after_training=True, points=model.mode == "rgbd")}'
        if (height, width) != model.trained_size:
            trained_height, trained_width = model.trained_size
            provenance += (f'; exported again at {width}x{height} from these weights (trained at '
                           f'{trained_width}x{trained_height}; the token positions learned on its grid '
                           'sampled in between)')
    else:
        provenance = checkpoint_provenance(args, model, json.loads(Path(args.summary).read_text()), guided)
    if rewrite and 'graph rewritten for the CPU runtime' not in provenance:
        provenance += f'; graph rewritten for the CPU runtime ({rewrite})'
    manifest = f'''# GroupForward-mini ({args.mode}), trained here on the simulator by train/train_recon.py. Not a
# pretrained paper model: {parameter_count(model) / 1e6:.2f} M parameters, small synthetic rooms only.
name = "{args.name}"
kind = "reconstruction"
file = "{args.name}.onnx"
mode = "{mode}"
input_height = {height}
input_width = {width}
embedding_dim = 8
provenance = "{provenance}; benchmarks below on {report['windows']} other val windows; ONNX parity {worst:.1e} of the outputs' scale; {size / 1e6:.1f} MB"
license = "Apache-2.0"

[normalization]
image_mean = [0.0, 0.0, 0.0]
image_std = [1.0, 1.0, 1.0]
points_scale = {POINTS_SCALE}
'''
    shapes = {'images': '[1, "V", 3, "H", "W"]', 'points': '[1, "V", 3, "H", "W"]', 'intrinsics': '[1, "V", 3, 3]',
              'world_from_camera': '[1, "V", 4, 4]'}
    manifest += '\n'.join(f'\n[[inputs]]\nname = "{n}"\nshape = {shapes[n]}' for n in names)
    manifest += '''

[[outputs]]
name = "depth"
shape = [1, "V", "H", "W"]

[[outputs]]
name = "gaussians"
shape = [1, "V", 11, "H", "W"]

[[outputs]]
name = "embeddings"
shape = [1, "V", 8, "H", "W"]
'''
    if votes:
        manifest += MANIFEST_OUTPUT
    manifest += benchmarks_section(report, size, parameter_count(model))
    (MODELS / f'{args.name}.toml').write_text(manifest)
    print(f'wrote {onnx_path} ({size / 1e6:.1f} MB) and its manifest; parity {worst:.2e}')


if __name__ == '__main__':
    main()
