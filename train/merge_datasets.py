"""Merge sim datasets of training splits into one directory train_recon.py reads: a symlink per
scene and one manifest listing them all (the first part's settings; every part must share them).

Usage: python3 train/merge_datasets.py OUT PART [PART ...]
(e.g. train/data/train and train/data/layouts_train, written by `groupforward sim dataset`)."""
import json
import os
import sys

TRAINING_SPLITS = ('train', 'layouts_train')
SHARED = ('format', 'version', 'views', 'width', 'height', 'fov_x_deg', 'depth_scale')


def merge(out, parts):
    os.makedirs(out, exist_ok=True)
    manifest, scenes, splits, effects = None, [], [], []
    for part in parts:
        m = json.load(open(os.path.join(part, 'dataset.json')))
        if m['split'] not in TRAINING_SPLITS:
            raise SystemExit(f'{part}: split {m["split"]!r} is no training split ({", ".join(TRAINING_SPLITS)})')
        splits.append(m['split'])
        if m.get('effects', 'clean') not in effects:
            effects.append(m.get('effects', 'clean'))
        if manifest is None:
            manifest = dict(m)
        elif any(m[k] != manifest[k] for k in SHARED):
            raise SystemExit(f'{part}: its {", ".join(SHARED)} differ from {parts[0]}')
        for scene in m['scenes']:
            link = os.path.join(out, scene)
            if not os.path.lexists(link):
                os.symlink(os.path.abspath(os.path.join(part, scene)), link)
            scenes.append(scene)
    # The parts' own splits, for the provenance of a model trained on the merge (train_recon.py).
    # Each part's sensor effects, so a model trained on a clean and a `realistic` part says both.
    manifest.update(split='train', scenes=scenes, samples=len(scenes), merged_from=list(parts), merged_splits=splits,
                    effects=effects[0] if len(effects) == 1 else effects)
    with open(os.path.join(out, 'dataset.json'), 'w') as f:
        json.dump(manifest, f, indent=1)
    return len(scenes)


if __name__ == '__main__':
    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    print(merge(sys.argv[1], sys.argv[2:]), 'scenes')
