"""Difficulty sampling (train_recon.py --window-weights): windows a model groups worse are drawn more
often, every window stays possible, and a score file that misses windows fails loudly:
`train/.venv/bin/python -m pytest -q train/tests`."""

import csv
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from train_recon import hard_share, window_weights  # noqa: E402


def write_scores(path, rows):
    with open(path, 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=['scene', 'ari', 'oracle_ari', 'room_kept', 'abs_rel'])
        writer.writeheader()
        for scene, ari in rows:
            writer.writerow({'scene': scene, 'ari': ari, 'oracle_ari': 1.0, 'room_kept': 1.0, 'abs_rel': 0.03})


def test_worse_grouped_windows_weigh_more_and_none_vanish(tmp_path):
    scores = tmp_path / 'train.csv'
    write_scores(scores, [('train_00001', 0.5), ('train_00000', 1.0), ('train_00002', 0.9)])
    weights = window_weights(scores, ['train_00000', 'train_00001', 'train_00002'], hard_weight=10.0)
    assert weights.tolist() == pytest.approx([1.0, 6.0, 2.0])  # in the dataset's order, not the file's
    assert hard_share(weights) == pytest.approx(6.0 / 9.0)
    assert hard_share(window_weights(scores, ['train_00000', 'train_00001'], hard_weight=0.0)) == 0.5


def test_negative_ari_still_gives_a_positive_finite_weight(tmp_path):
    scores = tmp_path / 'train.csv'
    write_scores(scores, [('train_00000', -0.2)])
    weights = window_weights(scores, ['train_00000'], hard_weight=10.0)
    assert torch.isfinite(weights).all() and float(weights[0]) == pytest.approx(13.0)


def test_a_window_without_a_score_is_an_error(tmp_path):
    scores = tmp_path / 'train.csv'
    write_scores(scores, [('train_00000', 0.9)])
    with pytest.raises(ValueError, match='no row for 1 train windows'):
        window_weights(scores, ['train_00000', 'train_00001'], hard_weight=10.0)
