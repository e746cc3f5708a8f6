"""Train Semantic-mini on simulator datasets (ARCHITECTURE.md §5: the LSeg role) and score it on val.

Per-pixel softmax over the label set's text embeddings (the node's int8 MiniLM; names and, as a
second softmax, descriptions; class 0 = `other`), cosines scaled by a learned logit scale, class
weights (median frequency / frequency)^½ so small objects count. Logits are computed at the
features' half resolution and upsampled to the label maps.

  train/.venv/bin/python train/train_semantic.py --train train/data/train --val train/data/val \\
      --minutes 45 --out train/runs/semantic

`--init models/semantic-mini.onnx` continues from an exported model (weights recovered from the ONNX
file, gf.recover; the logit scale, which the export drops, fitted to the first batches' loss).

Val metrics (`evaluate`): pixel accuracy and mIoU (classes present) with the class-name vocabulary;
the same with synonyms the model never trained on (`garbage can` for trash bin, `couch`, `fridge`,
...) swapped in; and instance accuracy: the masked-mean prototype of each ground-truth instance
(as the node pools them, §5.5) classified against the names.
"""

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gf.data import SimDataset  # noqa: E402
from gf.model import cpu_session, parameter_count  # noqa: E402
from gf.recover import recovered_semantic  # noqa: E402
from gf.semantic import SemanticMini, TextEncoder, label_set  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# Words for classes that training never sees (class id -> phrase).
SYNONYMS = {5: 'garbage can', 8: 'couch', 12: 'fridge', 10: 'bookcase', 13: 'computer screen', 14: 'houseplant',
            15: 'carton', 4: 'cupboard'}


def views_of(batch):
    """Flatten windows into images [N,3,H,W] and class maps [N,H,W]."""
    return batch['images'].flatten(0, 1), batch['class'].flatten(0, 1)


def class_weights(dataset, classes, power, windows=300):
    counts = np.zeros(classes)
    for i in range(min(windows, len(dataset))):
        counts += np.bincount(dataset[i]['class'].reshape(-1).numpy(), minlength=classes)[:classes]
    frequency = counts / counts.sum()
    present = frequency > 0
    weights = np.ones(classes)
    weights[present] = (np.median(frequency[present]) / frequency[present]) ** power
    return torch.from_numpy(weights).float()


def fitted_logit_scale(model, loader, names_text, descriptions_text, weights, batches=8):
    """The scale (on a log grid up to the training clamp, 100) whose training loss is lowest on
    the first `batches` batches: a recovered model's features were trained against a scale the
    export does not keep, and restarting from the initial 14 would first undo their sharpness."""
    model.eval()
    losses = {}
    grid = np.exp(np.linspace(np.log(5.0), np.log(100.0), 16))
    with torch.no_grad():
        for i, batch in enumerate(loader):
            if i >= batches:
                break
            images, classes = views_of(batch)
            features = model(images)
            for scale in grid:
                loss = pixel_loss(features, classes, (names_text, descriptions_text), scale, weights)[0]
                losses[scale] = losses.get(scale, 0.0) + loss.item()
    return float(min(losses, key=losses.get))


def pixel_loss(features, classes, texts, scale, weights):
    """The recipe's loss: the mean over `texts` (names, descriptions) of the per-pixel weighted
    cross-entropy, with each text's own term."""
    size = classes.shape[-2:]
    terms = [F.cross_entropy(logits(features, text, scale, size), classes, weight=weights) for text in texts]
    return sum(terms) / len(terms), terms


def instance_loss(features, instance, classes, text, scale, weights, windows):
    """Cross-entropy of each ground-truth instance's prototype as the node pools it (the masked mean
    of a window's features over the instance's pixels, sampled at the feature pixels' centres,
    ℓ2-normalised) against `text`, weighted like the pixels: the node names an instance by its
    prototype, so this trains the decision it makes rather than each pixel's."""
    n, d, h, w = features.shape
    views = n // windows
    stride_y, stride_x = instance.shape[-2] // h, instance.shape[-1] // w
    at_centres = (slice(None), slice(stride_y // 2, None, stride_y), slice(stride_x // 2, None, stride_x))
    ids, labels = instance[at_centres], classes[at_centres]
    prototypes, truth = [], []
    for window in range(windows):
        views_of_window = slice(window * views, (window + 1) * views)
        flat = features[views_of_window].permute(0, 2, 3, 1).reshape(-1, d)
        own, inverse = torch.unique(ids[views_of_window].reshape(-1), return_inverse=True)
        masks = F.one_hot(inverse, len(own)).float()  # pixels x instances
        prototypes.append(F.normalize(masks.T @ flat, dim=1))
        window_labels = labels[views_of_window].reshape(-1)
        truth.append(torch.stack([window_labels[inverse == k].mode().values for k in range(len(own))]))
    prototypes, truth = torch.cat(prototypes), torch.cat(truth)
    return F.cross_entropy(scale * prototypes @ text.T, truth, weight=weights)


def logits(features, text, scale, size):
    """Cosines of per-pixel features [N,D,h,w] to text [K,D] -> scaled logits [N,K,H,W] at `size`."""
    cosines = torch.einsum('ndhw,kd->nkhw', features, text)
    return F.interpolate(cosines * scale, size=size, mode='bilinear', align_corners=False)


def confusion_metrics(confusion):
    """(pixel accuracy, mIoU over the classes present, IoU per class id or None where absent)."""
    tp = np.diag(confusion)
    union = confusion.sum(0) + confusion.sum(1) - tp
    present = confusion.sum(1) > 0
    iou = tp / np.maximum(union, 1)
    per_class = [float(x) if p else None for x, p in zip(iou, present)]
    return float(tp.sum() / max(confusion.sum(), 1)), float(iou[present].mean()), per_class


@torch.no_grad()
def evaluate(model, dataset, names, names_text, synonyms_text, indices=None):
    model.eval()
    classes = names_text.shape[0]
    confusion = np.zeros((classes, classes), np.int64)
    confusion_synonyms = np.zeros((classes, classes), np.int64)
    instance_hits, instance_total = 0, 0
    indices = range(len(dataset)) if indices is None else indices
    for i in indices:
        item = dataset[i]
        images, truth = item['images'], item['class']
        features = model(images)
        size = truth.shape[-2:]
        for text, matrix in ((names_text, confusion), (synonyms_text, confusion_synonyms)):
            predicted = logits(features, text, 1.0, size).argmax(1)
            matrix += np.bincount((truth * classes + predicted).reshape(-1).numpy(),
                                  minlength=classes * classes).reshape(classes, classes)
        # Instance prototypes as the node pools them: masked means of the (upsampled) features.
        dense = F.interpolate(features, size=size, mode='bilinear', align_corners=False)
        instance = item['instance']
        for k in torch.unique(instance):
            mask = instance == k
            prototype = F.normalize(dense.permute(0, 2, 3, 1)[mask].mean(0), dim=0)
            label = truth[mask].mode().values.item()
            instance_hits += int((names_text @ prototype).argmax().item() == label)
            instance_total += 1
    accuracy, miou, class_iou = confusion_metrics(confusion)
    synonym_accuracy, synonym_miou, _ = confusion_metrics(confusion_synonyms)
    return {'pixel_accuracy': accuracy, 'miou': miou, 'synonym_pixel_accuracy': synonym_accuracy,
            'synonym_miou': synonym_miou, 'instance_accuracy': instance_hits / max(instance_total, 1),
            'instances': instance_total, 'windows': len(indices),
            'class_iou': {name: iou for name, iou in zip(names, class_iou) if iou is not None}}


def text_tables(dataset_json):
    names, descriptions = label_set(dataset_json)
    encoder = TextEncoder(ROOT / 'models')
    synonyms = [SYNONYMS.get(i, name) for i, name in enumerate(names)]
    return names, encoder.embed(names), encoder.embed(descriptions), encoder.embed(synonyms)


class OnnxSemantic:
    """The exported model (models/semantic-mini.onnx, one image per call) behind SemanticMini's call on a
    window's views, so the shipped file is scored by the same code as a checkpoint."""

    def __init__(self, path, threads):
        self.session = cpu_session(path, threads)

    def eval(self):
        return self

    def __call__(self, images):
        return torch.cat([torch.from_numpy(self.session.run(['features'], {'image': view[None].numpy()})[0])
                          for view in images])


def report(args):
    torch.set_num_threads(args.threads)
    val = SimDataset(args.val, 'rgb')
    names, names_text, _, synonyms_text = text_tables(Path(args.val) / 'dataset.json')
    if str(args.report).endswith('.onnx'):
        model = OnnxSemantic(args.report, args.threads)
    else:
        model = SemanticMini()
        model.load_state_dict(torch.load(args.report))
    held_out = range(0, max(0, len(val) - args.val_windows))
    print(json.dumps(evaluate(model, val, names, names_text, synonyms_text, held_out)))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--train', required=True)
    parser.add_argument('--val', required=True)
    parser.add_argument('--minutes', type=float, default=45.0, help='wall-clock budget')
    parser.add_argument('--steps', type=int, default=0,
                        help='a budget in steps instead of minutes (the schedule follows the step count), for '
                             'runs that share the machine with other work')
    parser.add_argument('--batch', type=int, default=2, help='windows per step (4 views each)')
    parser.add_argument('--lr', type=float, default=2e-3)
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument('--device', default='cpu', help='torch device that trains (cpu, cuda); val stays on the CPU')
    parser.add_argument('--eval-every', type=float, default=8.0, help='minutes between val evaluations')
    parser.add_argument('--val-windows', type=int, default=24,
                        help='the last N val windows pick the checkpoint; the rest stay held out for the report')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--class-weight-power', type=float, default=0.5,
                        help='class weights are (median frequency / frequency)^power: 0 = none, 1 = full balance')
    parser.add_argument('--instance-weight', type=float, default=0.0,
                        help='weight of a loss on the instances\' pooled prototypes (names and descriptions), '
                             'beside the per-pixel loss; 0 = the per-pixel recipe')
    parser.add_argument('--select', choices=('miou', 'instance_accuracy'), default='miou',
                        help='the val metric that picks the checkpoint: pixel mIoU, or instances named as the node '
                             'names them (a run with --instance-weight trades the first for the second)')
    parser.add_argument('--init', default=None, metavar='MODEL',
                        help='start from these weights (a train_semantic.py model.pt, or an exported models/<name>.onnx)')
    parser.add_argument('--out', default=None)
    parser.add_argument('--report', default=None, metavar='MODEL',
                        help='only score MODEL (model.pt, or the exported .onnx) on the val windows held out from '
                             'selection (--val-windows 0: all of them, e.g. val_test), print JSON')
    args = parser.parse_args()
    if args.report:
        report(args)
        return

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    assert args.out, '--out is required for training'
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    train = SimDataset(args.train, 'rgb')
    val = SimDataset(args.val, 'rgb')
    assert train.split == 'train' and val.split == 'val', 'train and val must come from their own splits'
    names, names_text, descriptions_text, synonyms_text = text_tables(Path(args.train) / 'dataset.json')
    weights = class_weights(train, len(names), args.class_weight_power)
    selection = range(max(0, len(val) - args.val_windows), len(val))
    model = SemanticMini()
    if args.init:
        if str(args.init).endswith('.onnx'):
            model = recovered_semantic(args.init)
            fit_loader = torch.utils.data.DataLoader(train, batch_size=args.batch, shuffle=False)
            scale = fitted_logit_scale(model, fit_loader, names_text, descriptions_text, weights)
            model.logit_scale.data.fill_(float(np.log(scale)))
            print(f'recovered {args.init}; logit scale fitted to {scale:.1f}', flush=True)
        else:
            model.load_state_dict(torch.load(args.init))
    device = torch.device(args.device)
    model.to(device)
    names_on_device, descriptions_on_device, weights_on_device = (
        names_text.to(device), descriptions_text.to(device), weights.to(device))
    print(f'Semantic-mini: {parameter_count(model) / 1e6:.2f} M parameters; {len(train)} train windows; '
          f'labels {names}; class weights {[round(w, 2) for w in weights.tolist()]}', flush=True)
    loader = torch.utils.data.DataLoader(train, batch_size=args.batch, shuffle=True, drop_last=True)
    optimizer = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=1e-4)
    budget = args.minutes * 60.0
    started = time.perf_counter()
    last_eval = started
    best = {args.select: -1.0}
    step = 0
    log = open(out / 'log.csv', 'w')
    log.write('step,seconds,loss,name_loss,description_loss\n')
    done = False
    while not done:
        for batch in loader:
            elapsed = time.perf_counter() - started
            progress = step / args.steps if args.steps else elapsed / budget
            if progress >= 1.0:
                done = True
                break
            # Cosine decay to a tenth over the budget.
            for group in optimizer.param_groups:
                group['lr'] = args.lr * (0.1 + 0.9 * 0.5 * (1 + np.cos(np.pi * progress)))
            model.train()
            images, classes = (tensor.to(device) for tensor in views_of(batch))
            instances = batch['instance'].flatten(0, 1).to(device)
            if torch.rand(()) < 0.5:  # left-right mirror: classes do not depend on handedness
                images, classes, instances = images.flip(-1), classes.flip(-1), instances.flip(-1)
            features = model(images)
            scale = model.logit_scale.exp().clamp(max=100.0)
            loss, (name_loss, description_loss) = pixel_loss(
                features, classes, (names_on_device, descriptions_on_device), scale, weights_on_device)
            if args.instance_weight > 0:
                pooled = sum(instance_loss(features, instances, classes, text, scale, weights_on_device,
                                           args.batch) for text in (names_on_device, descriptions_on_device))
                loss = loss + args.instance_weight * 0.5 * pooled
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            optimizer.step()
            step += 1
            log.write(f'{step},{elapsed:.1f},{loss.item():.5f},{name_loss.item():.5f},'
                      f'{description_loss.item():.5f}\n')
            if step % 50 == 0:
                log.flush()
                print(f'step {step} {elapsed / 60:.1f} min: loss {loss.item():.4f} (names {name_loss.item():.4f}, '
                      f'descriptions {description_loss.item():.4f}) scale {scale.item():.1f}', flush=True)
            now = time.perf_counter()
            if now - last_eval >= args.eval_every * 60.0:
                last_eval = now
                on_cpu = copy.deepcopy(model).cpu()
                metrics = evaluate(on_cpu, val, names, names_text, synonyms_text, selection)
                print(f'  val: {metrics}', flush=True)
                if metrics[args.select] > best[args.select]:
                    best = dict(metrics, step=step, minutes=elapsed / 60)
                    torch.save(on_cpu.state_dict(), out / 'model.pt')
    on_cpu = copy.deepcopy(model).cpu()
    metrics = evaluate(on_cpu, val, names, names_text, synonyms_text, selection)
    print(f'final val: {metrics}', flush=True)
    if metrics[args.select] > best[args.select]:
        best = dict(metrics, step=step, minutes=(time.perf_counter() - started) / 60)
        torch.save(on_cpu.state_dict(), out / 'model.pt')
    summary = {'steps': step, 'minutes': (time.perf_counter() - started) / 60, 'threads': args.threads,
               'device': args.device, 'train_effects': train.manifest.get('effects'),
               'train_windows': len(train), 'labels': names, 'best': best, 'final': metrics,
               'parameters': parameter_count(model), 'args': vars(args)}
    (out / 'summary.json').write_text(json.dumps(summary, indent=2))
    log.close()
    print(json.dumps(best))


if __name__ == '__main__':
    main()
