"""Train GroupForward-mini on simulator datasets with the three-stage curriculum of ARCHITECTURE.md §5.

  (1) reconstruction only, instance head frozen;  (2) instance head only;  (3) everything jointly;
  and, with --polish, (4) the instance head alone again for the last share of the budget.

Usage (from the repository root, after `make train-setup` and writing datasets with
`groupforward sim dataset --split train ...` / `--split val ...`):

  train/.venv/bin/python train/train_recon.py --train data/train --val data/val --mode rgbd \\
      --minutes 40 --out train/runs/rgbd

Fine-tuning a shipped model's instance head with the upsampling it ships with, e.g. `--init
models/<name>.onnx --guided 0.06,0.05 --stages 0 1 0 --decouple` (README, Training).

Writes <out>/model.pt (best val ARI), <out>/log.csv (step, stage, losses, seconds) and
<out>/summary.json. A run longer than a session: `--session-minutes M` stops it cleanly after M minutes
with its state in <out>/resume.pt (also written every --checkpoint-every steps, so a cut run loses at
most that many), and the same command with `--resume` continues it, taking the steps an uncut run
takes (gf.resume). CPU is enough (threads: --threads, default 2); `--device cuda` runs the same recipe
(steps, batch, schedule) on a GPU, faster, with validation still on the CPU.
"""

import argparse
import copy
import csv
import math
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gf.data import SimDataset  # noqa: E402
from gf.losses import (  # noqa: E402
    LAMBDA_DICE, LAMBDA_DIRECT, LAMBDA_FOCAL, LAMBDA_PULL, LAMBDA_PUSH, LAMBDA_RENDER, ROOM_VOTE, depth_loss,
    assignment_losses, direct_losses, rendered_losses, room_gate_loss, vote_loss)
from gf.model import GroupForwardMini, parameter_count  # noqa: E402
from gf.recover import model_from_file  # noqa: E402
from eval_recon import evaluate, guided_widths  # noqa: E402
from gf import resume  # noqa: E402


def stage_of(fraction, split, polish=0.0):
    """Curriculum stage for the share of the budget used: 1, 2, 3 by the shares `split` of the budget
    before the polish, then 4 (the instance head alone again) for the last `polish` of the budget."""
    if fraction >= 1.0 - polish:
        return 4
    first, second = (share * (1.0 - polish) for share in split[:2])
    if fraction < first:
        return 1
    if fraction < first + second:
        return 2
    return 3


def window_weights(path, scenes, hard_weight):
    """Sampling weights [len(scenes)] from eval_recon.py --per-window rows: 1 + hard_weight·(1 − ARI), so the
    windows the model groups worst (large objects filling a view, which it half gives to the room) come
    up more often without the easy ones vanishing. Every scene needs a row."""
    with open(path, newline='') as f:
        ari = {row['scene']: float(row['ari']) for row in csv.DictReader(f)}
    missing = [scene for scene in scenes if scene not in ari]
    if missing:
        raise ValueError(f'{path} has no row for {len(missing)} train windows (first: {missing[0]}); score the '
                         'whole train split with eval_recon.py --per-window')
    return torch.tensor([1.0 + hard_weight * (1.0 - ari[scene]) for scene in scenes], dtype=torch.float64)


def hard_share(weights):
    """The share of the draws that goes to the tenth of the windows with the largest weights."""
    top = weights.sort(descending=True).values[:max(1, len(weights) // 10)]
    return float(top.sum() / weights.sum())


def cpu_state(model):
    """Weights that load on any machine, whatever device trained them."""
    return {name: tensor.cpu() for name, tensor in model.state_dict().items()}


def float32(outputs):
    """The model's outputs as float32 (None stays None), so the losses never run in bfloat16."""
    return tuple(None if output is None else output.float() for output in outputs)


def cpu_name():
    """The CPU's model name and whether it has native bfloat16 (what sets a run's steps per minute)."""
    try:
        info = Path('/proc/cpuinfo').read_text()
    except OSError:
        return None
    name = next((line.split(':', 1)[1].strip() for line in info.splitlines() if line.startswith('model name')), None)
    return name and f"{name}{', avx512_bf16' if 'avx512_bf16' in info else ''}"


def evaluate_on_cpu(model, val, selection):
    """Validation as the node groups (HDBSCAN and numpy run on the CPU), on a copy of the model."""
    with torch.device('cpu'):
        return evaluate(copy.deepcopy(model).cpu(), val, selection)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--train', required=True)
    parser.add_argument('--val', required=True)
    parser.add_argument('--mode', choices=['rgbd', 'rgb'], default='rgbd')
    parser.add_argument('--minutes', type=float, default=40.0, help='wall-clock budget')
    parser.add_argument('--steps', type=int, default=0,
                        help='a budget in steps instead of minutes (curriculum and schedule follow the step '
                             'count), for comparisons that must not depend on machine load')
    parser.add_argument('--stages', type=float, nargs=3, default=[0.15, 0.25, 0.6],
                        help='budget shares of the three curriculum stages')
    parser.add_argument('--polish', type=float, default=0.0,
                        help='the last share of the budget trains the instance head alone again (stage 4, its '
                             'own optimizer, at the cosine schedule\'s low end), as a fine-tune of the joint '
                             'model would; the --stages shares then split the rest')
    parser.add_argument('--batch', type=int, default=2)
    parser.add_argument('--lr', type=float, default=2e-3)
    parser.add_argument('--schedule', choices=['cosine', 'constant'], default='cosine',
                        help='learning rate over the budget: cosine decay to 5%% of --lr, or constant')
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument('--device', default='cpu', help='torch device that trains (cpu, cuda)')
    parser.add_argument('--eval-every', type=float, default=8.0, help='minutes between val evaluations')
    parser.add_argument('--val-windows', type=int, default=24,
                        help='the last N val windows pick the checkpoint; the rest stay held out for the report')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--no-rendered', action='store_true',
                        help='direct losses only (the ablation): no rasterized dice/focal/embedding/photometric terms')
    parser.add_argument('--render-gaussians', type=int, default=2048,
                        help='Gaussians per window the rendered losses rasterize (at 1/4 resolution)')
    parser.add_argument('--pseudo-labels', default=None,
                        help='train on these instance ids (train/make_pseudo_labels.py) instead of the ground truth')
    parser.add_argument('--refine', action='store_true',
                        help='refine the instance embeddings at full resolution (an ablation; off by default)')
    parser.add_argument('--no-votes', action='store_true',
                        help='RGB-D: a plain instance head instead of 3D centre votes (the model before them)')
    parser.add_argument('--vote-weight', type=float, default=0.0,
                        help='RGB-D votes head: weight of the supervised centre-vote loss (gf.losses.vote_loss; '
                             '0 = votes trained by the embedding losses alone)')
    parser.add_argument('--room-vote', action='store_true',
                        help='with --vote-weight: walls and floor vote for a fixed point below the floor '
                             '(gf.losses.ROOM_VOTE) instead of having no vote target')
    parser.add_argument('--hard-push', action='store_true',
                        help='push hinge averaged over the violating centroid pairs only (gf.losses.direct_losses)')
    parser.add_argument('--vote-target', choices=('centroid', 'box'), default='centroid',
                        help="with --vote-weight: an object's pixels vote for the centroid of its points the window "
                             "sees, or for the centre of its whole box (the sim's truth), which every piece of it "
                             "agrees on")
    parser.add_argument('--touching-push', type=float, default=0.0,
                        help='weight of the push hinge over touching same-class instances (gf.losses.touching_pairs)')
    parser.add_argument('--direct-assignment', type=float, nargs='?', const=1.0, default=0.0,
                        help='dice + focal on the unrendered assignment probabilities of sampled pixels '
                             '(gf.losses.assignment_losses), weighted as the rendered ones times this '
                             'factor (1 when given without a value)')
    parser.add_argument('--room-gate', type=float, default=0.0,
                        help='gate every pixel\'s embedding towards one learned room vector by a predicted '
                             'wall-or-floor probability (gf.model room_gate), its cross-entropy '
                             '(gf.losses.room_gate_loss) weighted by this; 0 = no gate')
    parser.add_argument('--sharp-gate', action='store_true',
                        help='with --room-gate: correct the upsampled room logit at full resolution '
                             '(gf.model sharp_gate), so the gate follows object outlines pixel by pixel')
    parser.add_argument('--gate-per-pixel', action='store_true',
                        help='with --room-gate: its cross-entropy weighs every pixel alike instead of the room '
                             'and the objects equally (gf.losses.room_gate_loss)')
    parser.add_argument('--posed', action='store_true',
                        help='RGB mode with TF poses: a plane-sweep matching cost over the window\'s views '
                             '(gf.model.plane_sweep_cost) feeds the decoder, so depth can be triangulated')
    parser.add_argument('--sweep-depth', type=float, default=0.0,
                        help='with --posed: the plane sweep\'s own depth (soft-argmin over the planes) and '
                             'confidence also go to the decoder, and its depth loss, weighted by this, trains the '
                             'matching features directly; 0 = off')
    parser.add_argument('--decouple', action='store_true',
                        help='the instance losses stop at the instance head\'s inputs (gf.model forward_training '
                             'instance_gradient): in stage 3 the decoder and depth train on the depth losses alone, '
                             'so grouping losses (the room gate\'s above all) cannot trade depth away; the rendered '
                             'losses still reach depth through their rasterization (use with --no-rendered)')
    parser.add_argument('--init', default=None,
                        help='start from these weights (a train_recon.py model.pt, or an exported models/<name>.onnx '
                             'recovered by gf.recover, of the same architecture) instead of a random draw; with '
                             '--stages 0 0 1, a coupled stage 3 after a --decouple run')
    parser.add_argument('--guided', metavar='SIGMA_POINTS,SIGMA_COLOUR', type=guided_widths, default=None,
                        help='train with the instance head upsampled by joint bilateral upsampling guided by the '
                             'input (GroupForwardMini.enable_guided_upsampling), so the losses see the upsampling '
                             'the model ships with; default bilinear')
    parser.add_argument('--window-weights', metavar='CSV', default=None,
                        help='draw train windows by difficulty instead of uniformly: eval_recon.py --per-window '
                             'rows of the train split, scored by the model being fine-tuned (window_weights)')
    parser.add_argument('--hard-weight', type=float, default=10.0,
                        help='with --window-weights: window drawn with probability ∝ 1 + this × (1 − its ARI)')
    parser.add_argument('--snapshot-every', type=int, default=0,
                        help='also keep the weights every N steps (snapshot_<step>.pt), for equal-step comparisons')
    parser.add_argument('--checkpoint-every', type=int, default=200,
                        help='write <out>/resume.pt every N steps: the state --resume continues from (gf.resume)')
    parser.add_argument('--resume', action='store_true',
                        help='continue the run in --out from its resume.pt (the same arguments; start afresh when '
                             'there is none), e.g. the next session running the same command')
    parser.add_argument('--stop-at-step', type=int, default=0,
                        help='stop after this step with the state written, to be continued with --resume')
    parser.add_argument('--session-minutes', type=float, default=0.0,
                        help='stop after this many minutes of this process (the state written), so a run longer '
                             'than a session ends cleanly and the next session resumes it')
    parser.add_argument('--bf16', action='store_true',
                        help='run the forward pass under bfloat16 autocast (weights, optimizer and losses stay '
                             'float32): 1.3-1.5x the steps per minute on a CPU with AVX-512 BF16')
    parser.add_argument('--out', required=True)
    args = parser.parse_args()
    if not 0.0 <= args.polish < 1.0:
        parser.error('--polish is a share of the budget: at least 0 and below 1')
    if args.vote_target == 'box' and args.vote_weight <= 0:
        parser.error('--vote-target box needs --vote-weight > 0 (without it the vote loss is off)')
    if args.room_vote and args.vote_weight <= 0:
        parser.error('--room-vote needs --vote-weight > 0 (without it the vote loss is off)')
    if args.sweep_depth > 0 and not args.posed:
        parser.error('--sweep-depth needs --posed')
    if args.posed and args.mode != 'rgb':
        parser.error('--posed is RGB mode\'s (RGB-D mode takes world points)')
    if (args.sharp_gate or args.gate_per_pixel) and args.room_gate <= 0:
        parser.error('--sharp-gate and --gate-per-pixel need --room-gate > 0')

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    train = SimDataset(args.train, args.mode, args.pseudo_labels, box_centres=args.vote_target == 'box')
    # The sim splits it holds (a merged dataset's parts', train/merge_datasets.py), for the provenance.
    splits = train.manifest.get('merged_splits') or [train.split]
    val = SimDataset(args.val, args.mode)
    assert train.split == 'train' and val.split == 'val', 'train and val must come from their own splits'
    selection = range(max(0, len(val) - args.val_windows), len(val))
    model = GroupForwardMini(mode=args.mode, refine=args.refine,
                             centre_votes=False if args.no_votes else None, room_gate=args.room_gate > 0,
                             sharp_gate=args.sharp_gate, posed=args.posed, sweep_depth=args.sweep_depth > 0)
    if args.init:
        # Loaded into the model the flags built, so an architecture that differs fails loudly.
        state = model_from_file(args.init, args.mode, args.guided).state_dict()
        if 'instance_guide_sigmas' in state:
            model.enable_guided_upsampling(*state['instance_guide_sigmas'].tolist())
        model.load_state_dict(state)
    if args.guided:
        model.enable_guided_upsampling(*args.guided)
    # Data rendered at another size than the trained 128 x 96 (`sim dataset --width 192 --height 144`):
    # the token positions of the trained grid, sampled in between (export with the same --input-size).
    size = train.window_size
    if val.window_size != size:
        raise SystemExit(f'train and val windows differ in size: {size} against {val.window_size}')
    model.set_input_size(*size)
    device = torch.device(args.device)
    model.to(device)
    print(f'GroupForward-mini ({args.mode}): {parameter_count(model) / 1e6:.2f} M parameters; '
          f'{len(train)} train windows, {len(val)} val windows')
    weights = None
    if args.window_weights:
        weights = window_weights(args.window_weights, train.scenes, args.hard_weight)
        print(f'windows drawn by difficulty: the hardest tenth is {hard_share(weights):.0%} of the draws')
    order = resume.EpochOrder(len(train), args.seed, weights)
    # Its own generator for the workers' base seed, so making a loader draws nothing from torch's.
    loader = torch.utils.data.DataLoader(train, batch_size=args.batch, sampler=order, drop_last=True, num_workers=0,
                                         generator=torch.Generator().manual_seed(args.seed))
    optimizers = {
        1: torch.optim.AdamW(model.reconstruction_parameters(), lr=args.lr, weight_decay=1e-4),
        2: torch.optim.AdamW(model.instance_parameters(), lr=args.lr, weight_decay=1e-4),
        3: torch.optim.AdamW(model.parameters(), lr=args.lr / 2, weight_decay=1e-4),
        4: torch.optim.AdamW(model.instance_parameters(), lr=args.lr, weight_decay=1e-4),
    }
    budget = args.minutes * 60.0
    best = {'ari': -1.0}
    step, spent = 0, 0.0
    generator = torch.Generator(device=device).manual_seed(args.seed)
    state = resume.load(out) if args.resume else None
    if state is not None:
        changed = resume.changed_arguments(state['args'], vars(args))
        if changed:
            parser.error(f'{out / resume.CHECKPOINT} was written by a run with other arguments: {", ".join(changed)}')
        model.load_state_dict(state['model'])
        for k, optimizer in optimizers.items():
            optimizer.load_state_dict(state['optimizers'][k])
        step, spent, best = state['step'], state['seconds'], state['best']
        order.epoch, order.skip = state['epoch'], state['batches_in_epoch'] * args.batch
        resume.restore_random_states(state['random'], generator)
        print(f'resumed at step {step} ({spent / 60:.1f} min of training) from {out / resume.CHECKPOINT}')
    elif args.resume:
        print(f'nothing to resume in {out}: starting afresh')
    sessions = 1 + (state['sessions'] if state is not None else 0)
    # The training time so far counts: a budget in minutes and the curriculum go on where they stopped.
    session_started = time.perf_counter()
    started = session_started - spent
    last_eval = session_started
    log = open(out / 'log.csv', 'a' if state is not None else 'w', newline='')
    writer = csv.writer(log)
    if state is None:
        writer.writerow(['step', 'stage', 'seconds', 'loss', 'depth', 'pull', 'push', 'render', 'photometric',
                         'vote', 'assignment', 'room'])

    def checkpoint():
        resume.save(out, model_state=cpu_state(model), optimizers=optimizers, step=step,
                    seconds=time.perf_counter() - started, best=best, epoch=epoch,
                    batches_in_epoch=batches_in_epoch, generator=generator, args=vars(args),
                    sessions=sessions)

    done = stopped = False
    while not done:
        epoch, batches_in_epoch = order.epoch, order.skip // args.batch
        for batch in loader:
            batch = {key: value.to(device) for key, value in batch.items()}
            # Tensors the model and the losses make on the fly land beside the weights.
            with device:
                elapsed = time.perf_counter() - started
                progress = step / args.steps if args.steps else elapsed / budget
                if progress >= 1.0:
                    done = True
                    break
                stage = stage_of(progress, args.stages, args.polish)
                model.train()
                # Stages 2 and 4 step the instance head alone: a backward pass into the rest is wasted work.
                head_only = stage in (2, 4)
                with torch.autocast(device.type, dtype=torch.bfloat16, enabled=args.bf16):
                    outputs = model.forward_training(**model.inputs(batch),
                                                     instance_gradient=not (args.decouple or head_only))
                depth, gaussians, embeddings, votes, room_logits, sweep_depth = float32(outputs)
                l_depth = depth_loss(depth, batch['depth'])
                if sweep_depth is not None:
                    # Trains the matching features directly (nearest-neighbour half-resolution truth).
                    l_depth = l_depth + args.sweep_depth * depth_loss(sweep_depth, batch['depth'][:, :, ::2, ::2])
                pull, push = direct_losses(embeddings, batch['instance'], generator=generator, hard_push=args.hard_push,
                                           klass=batch['class'], touching_weight=args.touching_push)
                l_assignment = torch.zeros(())
                if args.direct_assignment:
                    dice, focal = assignment_losses(embeddings, batch['instance'], generator=generator)
                    l_assignment = args.direct_assignment * (LAMBDA_DICE * dice + LAMBDA_FOCAL * focal)
                l_vote = torch.zeros(())
                if args.vote_weight > 0 and votes is not None:
                    l_vote = vote_loss(votes, batch['points'], batch['depth'], batch['instance'],
                                       ROOM_VOTE if args.room_vote else None, batch.get('box_centres'))
                l_room = (room_gate_loss(room_logits, batch['instance'], balanced=not args.gate_per_pixel)
                          if room_logits is not None else torch.zeros(()))
                l_direct = (LAMBDA_PULL * pull + LAMBDA_PUSH * push + args.vote_weight * l_vote + l_assignment
                            + args.room_gate * l_room)
                l_render = torch.zeros(())
                l_photo = torch.zeros(())
                if not args.no_rendered:
                    dice, focal, r_pull, r_push, l_photo = rendered_losses(
                        depth, gaussians, embeddings, batch, count=args.render_gaussians, generator=generator)
                    l_render = (LAMBDA_DICE * dice + LAMBDA_FOCAL * focal + LAMBDA_PULL * r_pull
                                + LAMBDA_PUSH * r_push)
                if stage == 1:
                    loss = l_depth + l_photo
                elif head_only:
                    loss = LAMBDA_DIRECT * l_direct + LAMBDA_RENDER * l_render
                else:
                    loss = l_depth + l_photo + LAMBDA_DIRECT * l_direct + LAMBDA_RENDER * l_render
                optimizer = optimizers[stage]
                if args.schedule == 'cosine':
                    # One decay over the whole budget; stage 3 runs at half the rate (all weights move).
                    factor = 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * progress))
                    for group in optimizer.param_groups:
                        group['lr'] = args.lr * factor * (0.5 if stage == 3 else 1.0)
                # All gradients, not only this stage's parameters': stale ones from an earlier stage would
                # otherwise count in the clipping norm.
                model.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
                optimizer.step()
                step += 1
                batches_in_epoch += 1
                if args.snapshot_every and step % args.snapshot_every == 0:
                    torch.save(cpu_state(model), out / f'snapshot_{step}.pt')
                writer.writerow([step, stage, f'{elapsed:.1f}', f'{loss.item():.5f}', f'{l_depth.item():.5f}',
                                 f'{pull.item():.5f}', f'{push.item():.5f}', f'{l_render.item():.5f}',
                                 f'{l_photo.item():.5f}', f'{l_vote.item():.5f}', f'{l_assignment.item():.5f}',
                                 f'{l_room.item():.5f}'])
                if step % 20 == 0:
                    log.flush()
                    print(f'step {step} stage {stage} {elapsed / 60:.1f} min: depth {l_depth.item():.4f} '
                          f'pull {pull.item():.4f} push {push.item():.4f} render {l_render.item():.4f} '
                          f'photometric {l_photo.item():.4f} vote {l_vote.item():.4f} '
                          f'assignment {l_assignment.item():.4f} room {l_room.item():.4f}', flush=True)
                now = time.perf_counter()
                stopped = step == args.stop_at_step or (
                    args.session_minutes > 0 and now - session_started >= args.session_minutes * 60.0)
                if stopped or (args.checkpoint_every and step % args.checkpoint_every == 0):
                    checkpoint()
                if stopped:
                    done = True
                    break
                if stage >= 2 and now - last_eval >= args.eval_every * 60.0:
                    last_eval = now
                    metrics = evaluate_on_cpu(model, val, selection)
                    print(f'  val: {metrics}', flush=True)
                    if metrics['ari'] > best['ari']:
                        best = dict(metrics, step=step, minutes=elapsed / 60)
                        torch.save(cpu_state(model), out / 'model.pt')
    log.close()
    if stopped:
        print(f'stopped at step {step} ({(time.perf_counter() - started) / 60:.1f} min of training); '
              f'the same command with --resume continues it', flush=True)
        return
    checkpoint()
    metrics = evaluate_on_cpu(model, val, selection)
    print(f'final val: {metrics}', flush=True)
    if metrics['ari'] > best['ari']:
        best = dict(metrics, step=step, minutes=(time.perf_counter() - started) / 60)
        torch.save(cpu_state(model), out / 'model.pt')
    summary = {'mode': args.mode, 'rendered_losses': not args.no_rendered, 'steps': step,
               'minutes': (time.perf_counter() - started) / 60,
               'threads': args.threads, 'device': args.device, 'cpu': cpu_name(), 'seed': args.seed,
               'sessions': sessions, 'train_windows': len(train), 'train_size': [size[1], size[0]],
               'train_splits': splits,
               'val_windows': args.val_windows,
               'best': best, 'final': metrics, 'parameters': parameter_count(model),
               'args': vars(args)}
    (out / 'summary.json').write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary['best']))


if __name__ == '__main__':
    main()
