"""Reference metric values from scikit-image and scikit-learn for the Rust metrics (recon::metrics).

Run from the repository root after `make setup`:
    .venv/bin/pip install scikit-image==0.26.0 scikit-learn==1.9.1
    .venv/bin/python node/tests/reference/make_metrics_reference.py
Writes node/tests/reference/metrics.json (inputs and expected values). CI only reads the JSON.
"""

import json
from pathlib import Path

import numpy as np
from skimage.metrics import peak_signal_noise_ratio, structural_similarity
from sklearn.metrics import accuracy_score, adjusted_rand_score, jaccard_score

OUT = Path(__file__).resolve().parent / 'metrics.json'
rng = np.random.default_rng(20261121)


def f32(a):
    """float32 values (what the Rust side holds), as float64 for the reference computation."""
    return np.asarray(a, dtype=np.float32).astype(np.float64)


images = []
for (h, w, c, noise) in [(20, 24, 3, 0.05), (13, 16, 1, 0.2), (30, 30, 3, 0.01), (11, 11, 1, 0.3)]:
    target = f32(rng.random((h, w, c)))
    prediction = f32(np.clip(target + rng.normal(0, noise, target.shape), 0, 1))
    images.append({
        'width': w, 'height': h, 'channels': c,
        'target': target.ravel().tolist(), 'prediction': prediction.ravel().tolist(),
        'psnr': peak_signal_noise_ratio(target, prediction, data_range=1.0),
        'ssim': structural_similarity(target, prediction, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                      use_sample_covariance=False, channel_axis=-1),
    })

depth = []
for n in [50, 200]:
    target = f32(rng.uniform(0.3, 8.0, n))
    prediction = f32(target * rng.uniform(0.7, 1.4, n))
    target[::17] = np.nan   # invalid ground truth
    prediction[::23] = 0.0  # invalid prediction
    valid = np.isfinite(target) & np.isfinite(prediction) & (target > 0) & (prediction > 0)
    t, p = target[valid], prediction[valid]
    depth.append({
        'target': [None if np.isnan(v) else v for v in target.tolist()],
        'prediction': prediction.tolist(),
        'abs_rel': float(np.mean(np.abs(p - t) / t)),
        'delta1': float(np.mean(np.maximum(p / t, t / p) < 1.25)),
    })

semantic = []
for (n, k) in [(500, 5), (300, 8)]:
    target = rng.integers(0, k + 2, n)          # labels >= k are folded into `other`
    prediction = np.where(rng.random(n) < 0.7, target, rng.integers(0, k + 2, n))
    other = k - 1
    fold = lambda a: np.where(a >= k, other, a)  # noqa: E731
    t, p = fold(target), fold(prediction)
    semantic.append({
        'num_classes': k, 'other': other, 'target': target.tolist(), 'prediction': prediction.tolist(),
        'miou': jaccard_score(t, p, average='macro'),
        'pixel_accuracy': accuracy_score(t, p),
    })

ari = []
for n in [100, 1000]:
    a = rng.integers(0, 6, n)
    b = np.where(rng.random(n) < 0.8, a + 10, rng.integers(0, 9, n))
    ari.append({'a': a.tolist(), 'b': b.tolist(), 'ari': adjusted_rand_score(a, b)})

OUT.write_text(json.dumps({'images': images, 'depth': depth, 'semantic': semantic, 'ari': ari}) + '\n')
print(f'wrote {OUT}')
