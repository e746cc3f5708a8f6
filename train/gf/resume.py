"""Runs longer than a session: the training state a run continues from (`train_recon.py --resume`).

A session on these machines lasts 180 minutes and no process outlives it, while the shipped recipe
takes 90-130 minutes of training: a run stops (`--stop-at-step`, `--session-minutes`) or is cut, and
the next session continues it from `<out>/resume.pt`, written every `--checkpoint-every` steps. The
file holds everything the next step depends on: the weights, every stage's optimizer, the step, the
training time spent (budgets in minutes and the curriculum count it), the best checkpoint's metrics,
the random states, where the data order stands and how many processes (sessions) it took so far.
A resumed run takes the steps one that never stopped takes: bit for bit at one thread count in fp32
(train/tests/test_resume.py); the real recipe (bf16, 2 threads) is not bit-reproducible even uncut,
and a resumed run differs from an uncut one as two uncut runs differ (losses in the 4th digit).

The data order is a function of (seed, epoch) alone (`EpochOrder`), not of a random state shared
with everything else, so a resumed run skips the batches its epoch already served without loading
them.
"""

import os
import random
from pathlib import Path

import numpy as np
import torch

CHECKPOINT = 'resume.pt'

# Arguments a resumed run may change: where and how long it runs, not what it trains.
FREE_ARGUMENTS = {'resume', 'stop_at_step', 'session_minutes', 'checkpoint_every', 'threads'}


class EpochOrder(torch.utils.data.Sampler):
    """Window indices, epoch after epoch (each `iter` is the next epoch): a permutation drawn from
    (seed, epoch), or with `weights` that many draws with replacement. The first epoch served starts
    at `epoch`, skipping its first `skip` indices."""

    def __init__(self, count, seed, weights=None, epoch=0, skip=0):
        self.count, self.seed, self.weights = count, seed, weights
        self.epoch, self.skip = epoch, skip

    def indices(self, epoch):
        generator = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
        if self.weights is None:
            return torch.randperm(self.count, generator=generator).tolist()
        return torch.multinomial(self.weights, self.count, replacement=True, generator=generator).tolist()

    def __iter__(self):
        order = self.indices(self.epoch)[self.skip:]
        self.epoch, self.skip = self.epoch + 1, 0
        return iter(order)

    def __len__(self):
        return self.count


def random_states(generator):
    """Every random state a training step draws from: the losses' generator, torch's, numpy's and
    Python's (and the GPU's, where there is one)."""
    states = {'generator': generator.get_state(), 'torch': torch.get_rng_state(),
              'numpy': np.random.get_state(), 'python': random.getstate()}
    if torch.cuda.is_available():
        states['cuda'] = torch.cuda.get_rng_state_all()
    return states


def restore_random_states(states, generator):
    generator.set_state(states['generator'])
    torch.set_rng_state(states['torch'])
    np.random.set_state(states['numpy'])
    random.setstate(states['python'])
    if 'cuda' in states and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(states['cuda'])


def save(out, *, model_state, optimizers, step, seconds, best, epoch, batches_in_epoch, generator, args,
         sessions):
    """Write `<out>/resume.pt` whole or not at all (a run cut while writing keeps the previous one)."""
    path = Path(out) / CHECKPOINT
    partial = path.with_suffix('.partial')
    torch.save({'model': model_state, 'optimizers': {k: o.state_dict() for k, o in optimizers.items()},
                'step': step, 'seconds': seconds, 'best': best, 'epoch': epoch,
                'batches_in_epoch': batches_in_epoch, 'random': random_states(generator), 'args': args,
                'sessions': sessions},
               partial)
    os.replace(partial, path)


def load(out):
    """The state `save` wrote into `out`, or None when there is none."""
    path = Path(out) / CHECKPOINT
    if not path.exists():
        return None
    return torch.load(path, map_location='cpu', weights_only=False)


def changed_arguments(saved, current):
    """The arguments (other than FREE_ARGUMENTS) whose values differ between the run that wrote the
    checkpoint and this one: a resumed run must train what the first one trained."""
    keys = (set(saved) | set(current)) - FREE_ARGUMENTS
    return sorted(k for k in keys if saved.get(k) != current.get(k))
