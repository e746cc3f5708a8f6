"""eval_recon.evaluate's per-window rows and the standard error of its ARI, on a tiny fake dataset:
`train/.venv/bin/python -m pytest -q train/tests`."""

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from eval_recon import evaluate  # noqa: E402

VIEWS, HEIGHT, WIDTH = 2, 24, 32


class TwoBoxes:
    """Windows with the room and two boxes; in window 1 the right box is drawn one column wider in
    the truth than the fake model sees it."""

    manifest = {'classes': [{'id': 1, 'name': 'box'}]}
    scenes = ['val_00000', 'val_00001']

    def __len__(self):
        return len(self.scenes)

    def objects(self, index):
        return [{'instance_id': k, 'class_id': 1, 'color': [0.1 * k] * 3, 'bounds_min': [2.0 * k] * 3,
                 'bounds_max': [2.0 * k + 1] * 3} for k in (1, 2)]

    def __getitem__(self, index):
        instance = torch.zeros(VIEWS, HEIGHT, WIDTH, dtype=torch.int64)
        instance[:, 4:20, 2:12] = 1
        instance[:, 4:20, 18 - index:30] = 2
        return {'images': torch.rand(VIEWS, 3, HEIGHT, WIDTH), 'points': torch.zeros(VIEWS, 3, HEIGHT, WIDTH),
                'depth': torch.full((VIEWS, HEIGHT, WIDTH), 2.0), 'instance': instance,
                'cameras': torch.eye(4).repeat(VIEWS, 1, 1)}


class OneHotModel:
    """Embeddings one-hot on the instance each pixel belongs to in window 0's truth."""

    def eval(self):
        return self

    def inputs(self, batch):
        return {'depth': batch['depth']}

    def __call__(self, depth):
        truth = TwoBoxes()[0]['instance']
        embeddings = torch.nn.functional.one_hot(truth, 8).permute(0, 3, 1, 2).float()[None]
        return depth, torch.zeros(1), embeddings


def test_per_window_rows_and_standard_error():
    rows = []
    metrics = evaluate(OneHotModel(), TwoBoxes(), per_window=rows)
    assert [row['scene'] for row in rows] == TwoBoxes.scenes
    assert rows[0]['ari'] == pytest.approx(1.0) and rows[1]['ari'] < 1.0
    assert metrics['ari'] == pytest.approx(np.mean([row['ari'] for row in rows]))
    expected_se = np.std([row['ari'] for row in rows], ddof=1) / np.sqrt(2)
    assert metrics['ari_se'] == pytest.approx(expected_se) and metrics['ari_se'] > 0
    assert all(row['abs_rel'] == pytest.approx(0.0) for row in rows)


def test_one_window_has_no_standard_error():
    assert evaluate(OneHotModel(), TwoBoxes(), indices=[0])['ari_se'] is None
