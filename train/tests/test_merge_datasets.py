"""train/merge_datasets.py: training splits merge into one manifest of symlinked scenes; a val or
benchmark dataset, or one rendered differently, is refused."""
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from merge_datasets import merge  # noqa: E402


def dataset(root, split, scenes, width=128, effects='clean'):
    root.mkdir()
    for scene in scenes:
        (root / scene).mkdir()
        (root / scene / 'cameras.json').write_text('{}')
    manifest = {'format': 'groupforward-sim-dataset', 'version': 1, 'split': split, 'views': 4,
                'width': width, 'height': 96, 'fov_x_deg': 60.0, 'depth_scale': 0.001, 'scenes': scenes,
                'effects': effects}
    (root / 'dataset.json').write_text(json.dumps(manifest))
    return root


def test_training_splits_merge_into_one_manifest_of_their_scenes(tmp_path):
    a = dataset(tmp_path / 'train', 'train', ['train_00000', 'train_00001'])
    b = dataset(tmp_path / 'rows', 'layouts_train', ['layouts_train_00000'])
    assert merge(tmp_path / 'both', [str(a), str(b)]) == 3
    manifest = json.loads((tmp_path / 'both' / 'dataset.json').read_text())
    assert manifest['split'] == 'train' and manifest['samples'] == 3
    assert manifest['merged_splits'] == ['train', 'layouts_train']
    assert (tmp_path / 'both' / 'layouts_train_00000' / 'cameras.json').exists()
    assert manifest['effects'] == 'clean'


def test_parts_rendered_with_different_effects_are_all_named(tmp_path):
    clean = dataset(tmp_path / 'clean', 'train', ['train_00000'])
    noisy = dataset(tmp_path / 'noisy', 'train', ['train_00001'], effects='realistic')
    merge(tmp_path / 'both', [str(clean), str(noisy)])
    assert json.loads((tmp_path / 'both' / 'dataset.json').read_text())['effects'] == ['clean', 'realistic']


def test_a_held_out_split_or_another_rendering_is_refused(tmp_path):
    a = dataset(tmp_path / 'train', 'train', ['train_00000'])
    val = dataset(tmp_path / 'val', 'val', ['val_00000'])
    wide = dataset(tmp_path / 'wide', 'layouts_train', ['layouts_train_00000'], width=256)
    with pytest.raises(SystemExit, match='no training split'):
        merge(tmp_path / 'x', [str(a), str(val)])
    with pytest.raises(SystemExit, match='differ'):
        merge(tmp_path / 'y', [str(a), str(wide)])
