"""A run stopped and resumed takes the same steps as one that never stopped (gf.resume, train_recon.py
--resume / --stop-at-step), on a tiny dataset in the simulator's layout written here."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

TRAIN = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TRAIN))
from gf.resume import CHECKPOINT, EpochOrder  # noqa: E402

HEIGHT, WIDTH, VIEWS = 96, 128, 2


def write_dataset(root, split, scenes):
    """`scenes` windows of two views: a floor at 2 m and two boxes at 1.5 m, shifted per scene."""
    root.mkdir(parents=True)
    names = [f'{split}_{i:05d}' for i in range(scenes)]
    classes = [{'id': 0, 'name': 'other'}, {'id': 1, 'name': 'box'}]
    (root / 'dataset.json').write_text(json.dumps({'split': split, 'scenes': names, 'classes': classes}))
    rng = np.random.default_rng(len(split))
    for i, name in enumerate(names):
        scene = root / name
        scene.mkdir()
        views = []
        for v in range(VIEWS):
            instance = np.zeros((HEIGHT, WIDTH), np.uint16)
            instance[20:60, 10 + 4 * i:50 + 4 * i] = 1
            instance[30:80, 70:110 - 3 * v] = 2
            depth = np.where(instance > 0, 1500, 2000).astype(np.uint16)
            rgb = (rng.random((HEIGHT, WIDTH, 3)) * 60 + instance[..., None] * 60).astype(np.uint8)
            pose = np.eye(4)
            pose[0, 3] = 0.2 * v
            files = {kind: f'view_{v:02d}_{kind}.png' for kind in ('rgb', 'depth', 'instance', 'class')}
            Image.fromarray(rgb).save(scene / files['rgb'])
            Image.fromarray(depth).save(scene / files['depth'])
            Image.fromarray(instance).save(scene / files['instance'])
            Image.fromarray((instance > 0).astype(np.uint8)).save(scene / files['class'])
            views.append(dict(files, k=[100.0, 0, WIDTH / 2, 0, 100.0, HEIGHT / 2, 0, 0, 1],
                              world_from_camera=pose.tolist()))
        objects = [{'instance_id': k, 'class_id': 1, 'color': [0.5, 0.5, 0.5],
                    'bounds_min': [0.3 * k, 0.0, 1.4], 'bounds_max': [0.3 * k + 0.25, 0.3, 1.7]} for k in (1, 2)]
        (scene / 'cameras.json').write_text(json.dumps({'views': views, 'objects': objects}))


def train(data, out, *extra):
    command = [sys.executable, str(TRAIN / 'train_recon.py'), '--train', str(data / 'train'),
               '--val', str(data / 'val'), '--mode', 'rgbd', '--threads', '1', '--seed', '3', '--no-rendered',
               '--vote-weight', '1', '--room-gate', '1', '--stages', '0', '0', '1', '--steps', '4',
               '--val-windows', '1', '--eval-every', '1000', '--out', str(out), *extra]
    return subprocess.run(command, capture_output=True, text=True, cwd=TRAIN.parent)


def losses(out):
    with open(out / 'log.csv', newline='') as f:
        return [(row['step'], row['loss']) for row in csv.DictReader(f)]


def test_a_stopped_and_resumed_run_ends_with_the_weights_of_one_that_never_stopped(tmp_path):
    write_dataset(tmp_path / 'train', 'train', 3)
    write_dataset(tmp_path / 'val', 'val', 1)
    straight = train(tmp_path, tmp_path / 'straight')
    assert straight.returncode == 0, straight.stderr
    first = train(tmp_path, tmp_path / 'cut', '--stop-at-step', '2', '--resume')
    assert first.returncode == 0, first.stderr
    assert 'stopped at step 2' in first.stdout
    assert not (tmp_path / 'cut' / 'summary.json').exists()
    # The next session runs the same command, without the stop (at another thread count the sums
    # round differently: equal to rounding, not bit for bit).
    second = train(tmp_path, tmp_path / 'cut', '--resume')
    assert second.returncode == 0, second.stderr
    assert 'resumed at step 2' in second.stdout
    a = torch.load(tmp_path / 'straight' / CHECKPOINT, weights_only=False)
    b = torch.load(tmp_path / 'cut' / CHECKPOINT, weights_only=False)
    assert a['step'] == b['step'] == 4
    assert a['model'].keys() == b['model'].keys()
    # Batches of 2 over 3 windows: one batch an epoch, so the next step is epoch 4's first.
    assert (a['epoch'], a['batches_in_epoch']) == (b['epoch'], b['batches_in_epoch']) == (4, 0)
    different = [name for name in a['model'] if not torch.equal(a['model'][name], b['model'][name])]
    assert not different, different
    assert losses(tmp_path / 'straight') == losses(tmp_path / 'cut')
    summary = json.loads((tmp_path / 'cut' / 'summary.json').read_text())
    assert summary['steps'] == 4


def test_a_resumed_run_with_other_training_arguments_is_refused(tmp_path):
    write_dataset(tmp_path / 'train', 'train', 2)
    write_dataset(tmp_path / 'val', 'val', 1)
    assert train(tmp_path, tmp_path / 'run', '--stop-at-step', '1').returncode == 0
    refused = train(tmp_path, tmp_path / 'run', '--resume', '--lr', '1e-5')
    assert refused.returncode == 2
    assert 'other arguments: lr' in refused.stderr


def test_an_epoch_resumed_part_way_serves_the_rest_of_the_same_order():
    weights = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0], dtype=torch.float64)
    for w in (None, weights):
        whole = EpochOrder(5, seed=7, weights=w)
        epochs = [list(whole) for _ in range(3)]
        assert epochs[0] != epochs[1]
        resumed = EpochOrder(5, seed=7, weights=w, epoch=1, skip=2)
        assert list(resumed) == epochs[1][2:]
        assert list(resumed) == epochs[2]
