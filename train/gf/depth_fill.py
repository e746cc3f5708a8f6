"""Hole filling of invalid depth for the RGB-D model's input, the same rule as the node's
`fill_invalid_depth` (node/src/model/reconstruction.rs). No torch: tests/tests/depth_fill_parity.rs runs it
from the test venv and holds it against the Rust function bit for bit."""

import numpy as np


def fill_invalid_depth(depth):
    """[H,W] depth with every invalid pixel (0, NaN, inf) that a chain of pixels connects to a valid one
    filled: each pass gives an invalid pixel with a valid 4-neighbour the largest such neighbour (holes at
    edges belong to the occluded background). A view without any valid pixel comes back unchanged. The
    same rule as node/src/model/reconstruction.rs, for the model's input only."""
    out = np.array(depth, dtype=np.float32, copy=True)
    valid = np.isfinite(out) & (out > 0)
    if valid.all() or not valid.any():
        return out
    out[~valid] = np.nan
    while True:
        invalid = np.isnan(out)
        padded = np.pad(out, 1, constant_values=np.nan)
        neighbours = np.stack([padded[1:-1, :-2], padded[1:-1, 2:], padded[:-2, 1:-1], padded[2:, 1:-1]])
        has = np.isfinite(neighbours).any(axis=0)
        fill = invalid & has
        if not fill.any():
            break
        best = np.where(np.isfinite(neighbours), neighbours, -np.inf).max(axis=0)
        out[fill] = best[fill]
    return out
