"""Semantic-mini (the LSeg role, ARCHITECTURE.md §5): one image in, dense features aligned with the
all-MiniLM-L6-v2 text embedding space out.

`image` [1,3,H,W] in [0,1] -> `features` [1,384,H/2,W/2], ℓ2-normalised per pixel, so a pixel's (or
an instance prototype's) cosine to a phrase's text embedding scores the phrase. Trained as LSeg is:
per-pixel softmax over the text embeddings of the label set (16 object classes by name, and by
description, plus an explicit `other` for walls, floor and anything unnamed), the text encoder frozen.
A U-Net encoder with one self-attention layer over the bottleneck tokens for whole-image context.
"""

import json
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from .model import CrossViewAttention, block, positional_encoding

FEATURE_DIM = 384
OTHER = 'other'


class SemanticMini(nn.Module):
    def __init__(self, height=96, width=128, feature_dim=FEATURE_DIM):
        super().__init__()
        # Narrower than GroupForward-mini: the committed models share a 15 MB budget.
        c = [24, 48, 64, 96]
        self.enc1 = block(3, c[0], stride=2)
        self.enc2 = block(c[0], c[1], stride=2)
        self.enc3 = block(c[1], c[2], stride=2)
        self.enc4 = block(c[2], c[3], stride=2)
        self.register_buffer('position', positional_encoding(height // 16, width // 16, c[3]), persistent=False)
        self.attention = CrossViewAttention(c[3])
        self.dec3 = block(c[3] + c[2], c[2])
        self.dec2 = block(c[2] + c[1], c[1])
        self.dec1 = block(c[1] + c[0] + 3, 48)
        self.head = nn.Conv2d(48, feature_dim, 1)
        # exp(logit_scale) multiplies cosines in the training softmax (CLIP-style, starts at 1/0.07).
        self.logit_scale = nn.Parameter(torch.tensor(float(np.log(1 / 0.07))))

    def forward(self, image):
        e1 = self.enc1(image)
        e2 = self.enc2(e1)
        e3 = self.enc3(e2)
        e4 = self.enc4(e3)
        n, d, h, w = e4.shape
        tokens = (e4 + self.position).reshape(n, d, h * w).transpose(1, 2)
        e4 = self.attention(tokens).transpose(1, 2).reshape(n, d, h, w)
        up = lambda t: F.interpolate(t, scale_factor=2.0, mode='nearest')  # noqa: E731
        d3 = self.dec3(torch.cat([up(e4), e3], dim=1))
        d2 = self.dec2(torch.cat([up(d3), e2], dim=1))
        d1 = self.dec1(torch.cat([up(d2), e1, F.avg_pool2d(image, 2)], dim=1))
        return F.normalize(self.head(d1), dim=1)


class TextEncoder:
    """The node's text encoder (models/all-MiniLM-L6-v2.int8.onnx + tokenizer.json) through
    onnxruntime, so training aligns with exactly the embeddings the node computes."""

    def __init__(self, models_dir):
        import onnxruntime
        import tomllib
        from tokenizers import Tokenizer

        models_dir = Path(models_dir)
        manifest = tomllib.loads((models_dir / 'all-MiniLM-L6-v2.toml').read_text())
        self.tokenizer = Tokenizer.from_file(str(models_dir / manifest['tokenizer']))
        self.session = onnxruntime.InferenceSession(str(models_dir / manifest['file']),
                                                    providers=['CPUExecutionProvider'])

    def embed(self, phrases):
        out = []
        for phrase in phrases:
            ids = np.asarray([self.tokenizer.encode(phrase).ids], np.int64)
            (embedding,) = self.session.run(['embedding'], {'input_ids': ids, 'attention_mask': np.ones_like(ids)})
            out.append(embedding[0])
        return torch.from_numpy(np.stack(out)).float()


def label_set(dataset_json):
    """(names, descriptions) indexed by class id, with class 0 (walls, floor) as `other`."""
    classes = json.loads(Path(dataset_json).read_text())['classes']
    names = [OTHER] + [c['name'] for c in sorted(classes, key=lambda c: c['id'])]
    descriptions = [OTHER] + [c['description'] for c in sorted(classes, key=lambda c: c['id'])]
    assert [c['id'] for c in sorted(classes, key=lambda c: c['id'])] == list(range(1, len(names)))
    return names, descriptions
