"""Pseudo instance labels for a sim dataset split (train/gf/pseudo.py), for training without
ground-truth instances.

The per-view masks stand in for a per-view segmenter (SAM2's role): each view's ground-truth
instance mask, relabelled with ids that do not agree across views; nothing cross-view comes from
the ground truth. Cross-view ids come from `associate` with depth predicted by a stage-1 (reconstruction-
only) checkpoint. Writes <out>/<scene>.npy (int32 [V,H,W]) and <out>/quality.json (ARI of the
pseudo-labels against the ground-truth window instances, over all windows).

  train/.venv/bin/python train/make_pseudo_labels.py --data train/data/train \\
      --stage1 train/runs/rgbd_directonly/snapshot_1000.pt --out train/data/pseudo_train
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from sklearn.metrics import adjusted_rand_score

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gf.data import SimDataset  # noqa: E402
from gf.model import GroupForwardMini  # noqa: E402
from gf.pseudo import associate, per_view_masks  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--data', required=True)
    parser.add_argument('--stage1', required=True, help='reconstruction checkpoint whose depth is used')
    parser.add_argument('--mode', choices=['rgbd', 'rgb'], default='rgbd')
    parser.add_argument('--threads', type=int, default=1)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--out', required=True)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    dataset = SimDataset(args.data, args.mode)
    model = GroupForwardMini.from_state_dict(torch.load(args.stage1), args.mode)
    model.eval()
    rng = np.random.default_rng(args.seed)
    aris, per_view_aris = [], []
    started = time.perf_counter()
    for i in range(len(dataset)):
        item = dataset[i]
        with torch.no_grad():
            depth, _, _ = model(item['images'][None], item['points'][None] if args.mode == 'rgbd' else None)
        truth = item['instance'].numpy()
        masks = per_view_masks(truth, rng)
        labels = associate(masks, depth[0].numpy().astype(np.float64), item['k'].numpy(),
                           item['world_from_camera'].numpy())
        np.save(out / f'{dataset.scenes[i]}.npy', labels.astype(np.int32))
        aris.append(adjusted_rand_score(truth.reshape(-1), labels.reshape(-1)))
        per_view_aris.append(adjusted_rand_score(truth.reshape(-1), masks.reshape(-1)))
        if (i + 1) % 200 == 0:
            print(f'{i + 1}/{len(dataset)}: pseudo-label ARI {np.mean(aris):.3f} '
                  f'({time.perf_counter() - started:.0f} s)', flush=True)
    quality = {'windows': len(dataset), 'pseudo_label_ari': float(np.mean(aris)),
               'unassociated_ari': float(np.mean(per_view_aris)), 'stage1': args.stage1,
               'seconds': time.perf_counter() - started}
    (out / 'quality.json').write_text(json.dumps(quality, indent=2))
    print(json.dumps(quality))


if __name__ == '__main__':
    main()
