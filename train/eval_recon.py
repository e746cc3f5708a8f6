"""Validation metrics of a reconstruction model on a sim dataset split.

Instance grouping as the node does it: HDBSCAN (Python `hdbscan`, min_cluster_size 80, min_samples 10)
on the ℓ2-normalised predicted embeddings of all pixels of a window's views (every 2nd pixel), scored
with ARI against the ground-truth instances (walls and floor = one instance; noise stays its own
label). Depth: abs-rel and δ<1.25 over valid pixels.

  train/.venv/bin/python train/eval_recon.py --model train/runs/rgbd/model.pt --val data/val --mode rgbd
"""

import argparse
import json
import sys
from pathlib import Path

import hdbscan
import numpy as np
import torch
from sklearn.metrics import adjusted_rand_score

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gf.data import SimDataset  # noqa: E402
from gf.model import GroupForwardMini  # noqa: E402


@torch.no_grad()
def evaluate(model, dataset, mode, windows=None, stride=2, min_cluster_size=80, min_samples=10):
    model.eval()
    aris, abs_rel, delta = [], [], []
    count = len(dataset) if windows is None else min(windows, len(dataset))
    for i in range(count):
        item = dataset[i]
        images = item['images'][None]
        points = item['points'][None] if mode == 'rgbd' else None
        depth, _, embeddings = model(images, points)
        e = embeddings[0].permute(0, 2, 3, 1).reshape(-1, embeddings.shape[2])
        e = torch.nn.functional.normalize(e, dim=1).numpy()[::stride]
        truth = item['instance'].reshape(-1).numpy()[::stride]
        labels = hdbscan.HDBSCAN(min_cluster_size=min_cluster_size, min_samples=min_samples).fit_predict(
            e.astype(np.float64))
        aris.append(adjusted_rand_score(truth, labels))
        target = item['depth']
        valid = target > 0
        ratio = depth[0][valid] / target[valid]
        abs_rel.append(((depth[0][valid] - target[valid]).abs() / target[valid]).mean().item())
        delta.append((torch.maximum(ratio, 1 / ratio) < 1.25).float().mean().item())
    return {'ari': float(np.mean(aris)), 'abs_rel': float(np.mean(abs_rel)), 'delta1': float(np.mean(delta)),
            'windows': count}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--model', required=True)
    parser.add_argument('--val', required=True)
    parser.add_argument('--mode', choices=['rgbd', 'rgb'], default='rgbd')
    parser.add_argument('--windows', type=int, default=None)
    parser.add_argument('--threads', type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = GroupForwardMini(mode=args.mode)
    model.load_state_dict(torch.load(args.model))
    print(json.dumps(evaluate(model, SimDataset(args.val, args.mode), args.mode, args.windows)))


if __name__ == '__main__':
    main()
