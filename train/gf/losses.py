"""Losses of ARCHITECTURE.md §5 (the direct terms; rendered terms come with the differentiable rasterizer).

Direct: N context pixels are sampled per window with weight 1/sqrt(instance area) (so small objects
count), their embeddings ℓ2-normalised; centroids are the normalised means per instance;
L_pull = mean_n ‖e_n − ē_{y_n}‖, L_push = mean_{k≠l} [m − ‖ē_k − ē_l‖]₊ with m = 1. Walls and floor
(instance 0) are one background instance. Depth: L1 on log depth over valid pixels.

Centre votes (an addition to §5.3, training only, `vote_loss`): every object pixel's vote should be
its instance's 3D centroid in the window, or (`box_centres`) the centre of the object's whole box,
which every piece of it agrees on however little of it the window sees; optionally (`room_target`)
every wall and floor pixel's vote a fixed point below the floor, where no object's centre can be.
"""

import torch
from torch.nn import functional as F

LAMBDA_PULL = 0.5
LAMBDA_PUSH = 0.5
LAMBDA_DIRECT = 1.0
MARGIN = 1.0
LAMBDA_DICE = 0.5
LAMBDA_FOCAL = 0.5
LAMBDA_RENDER = 1.0
TAU = 0.1
# The room's vote target with `--room-vote`, in the model's scaled world units (centred on the mean
# camera centre, 3 m per unit): 4.5 m below the cameras, metres under any floor, and not at a whole
# period of the votes' Fourier features from the objects' centres (z ≈ −0.5 to 0.2).
ROOM_VOTE = (0.0, 0.0, -1.5)


def sample_pixels(instance, count, generator=None):
    """Indices of `count` pixels of one window (flattened over views), weighted by 1/sqrt(area)."""
    flat = instance.reshape(-1)
    ids, inverse, areas = torch.unique(flat, return_inverse=True, return_counts=True)
    weights = 1.0 / areas.float().sqrt()
    return torch.multinomial(weights[inverse], count, replacement=True, generator=generator)


def sampled_embeddings(embeddings, instance, samples, generator=None):
    """Sampled pixels of one window (embeddings [V,D,H,W], instance [V,H,W]): their unit embeddings
    [N,D], instance labels 0..K-1 [N] and the unit centroids [K,D] of each instance's samples."""
    e, labels, centroids, _ = sampled_with_ids(embeddings, instance, samples, generator)
    return e, labels, centroids


def sampled_with_ids(embeddings, instance, samples, generator=None):
    """`sampled_embeddings` and the instance id [K] of each centroid."""
    e = embeddings.permute(0, 2, 3, 1).reshape(-1, embeddings.shape[1])
    y = instance.reshape(-1)
    index = sample_pixels(y, samples, generator)
    e = F.normalize(e[index], dim=1)
    ids, labels = torch.unique(y[index], return_inverse=True)
    centroids = F.normalize(torch.zeros(ids.numel(), e.shape[1]).index_add_(0, labels, e), dim=1)
    return e, labels, centroids, ids


def touching_pairs(instance, klass):
    """Pairs of objects of one class whose pixels are 4-neighbours in some view of one window
    (instance, klass [V,H,W]; the room, id 0, left out): [P,2] instance ids, the smaller first.
    These are the pairs a grouping folds into one (a row of cabinets, two chairs side by side)."""
    keys = []
    for dy, dx in ((0, 1), (1, 0)):
        height, width = instance.shape[1] - dy, instance.shape[2] - dx
        a, b = instance[:, :height, :width], instance[:, dy:, dx:]
        same_class = klass[:, :height, :width] == klass[:, dy:, dx:]
        border = (a != b) & (a > 0) & (b > 0) & same_class
        low, high = torch.minimum(a[border], b[border]), torch.maximum(a[border], b[border])
        keys.append(low * 65536 + high)
    keys = torch.unique(torch.cat(keys))
    return torch.stack([keys // 65536, keys % 65536], dim=1)


def touching_push(centroids, ids, pairs):
    """Mean push hinge over the touching pairs whose both instances were sampled (0 when none)."""
    index = {int(i): k for k, i in enumerate(ids.tolist())}
    sampled = [(index[int(a)], index[int(b)]) for a, b in pairs.tolist() if int(a) in index and int(b) in index]
    if not sampled:
        return torch.zeros(())
    first, second = (torch.tensor(side) for side in zip(*sampled))
    return F.relu(MARGIN - (centroids[first] - centroids[second]).norm(dim=1)).mean()


def direct_losses(embeddings, instance, samples=4096, generator=None, hard_push=False, klass=None,
                  touching_weight=0.0):
    """embeddings [B,V,D,H,W], instance [B,V,H,W] -> (pull, push) averaged over the batch.
    `hard_push` (an experiment, off by default) averages the push hinge over the violating pairs only,
    not over all k ≠ l: with a dozen instances in a window, most pairs are already apart and the
    plain mean dilutes the few close ones (a pillow on its bed) by the number of pairs.
    `touching_weight` (with `klass` [B,V,H,W]) adds that times the mean hinge over the touching
    same-class pairs (`touching_pairs`), which the plain mean dilutes the same way."""
    pulls, pushes = [], []
    for b in range(embeddings.shape[0]):
        e, labels, centroids, ids = sampled_with_ids(embeddings[b], instance[b], samples, generator)
        k = centroids.shape[0]
        pulls.append((e - centroids[labels]).norm(dim=1).mean())
        if k > 1:
            distances = torch.cdist(centroids, centroids)
            off_diagonal = ~torch.eye(k, dtype=torch.bool)
            hinge = F.relu(MARGIN - distances[off_diagonal])
            if hard_push:
                push = hinge.sum() / (hinge > 0).sum().clamp_min(1)
            else:
                push = hinge.mean()
            if touching_weight > 0 and klass is not None:
                push = push + touching_weight * touching_push(centroids, ids, touching_pairs(instance[b], klass[b]))
            pushes.append(push)
        else:
            pushes.append(torch.zeros(()))
    return torch.stack(pulls).mean(), torch.stack(pushes).mean()


def assignment_losses(embeddings, instance, samples=4096, generator=None):
    """The rendered dice + focal terms of §5.3 on the pixel-aligned Gaussians themselves, without the
    rasterizer (an experiment, off by default): p_nk = softmax_k(−‖e_n − ē_k‖/τ) of sampled context
    pixels against their instances. Every pixel, not only every centroid, must be nearer its own
    instance than any other, at a small fraction of the rendered losses' cost.
    embeddings [B,V,D,H,W], instance [B,V,H,W] -> (dice, focal) averaged over the batch."""
    dices, focals = [], []
    for b in range(embeddings.shape[0]):
        e, labels, centroids = sampled_embeddings(embeddings[b], instance[b], samples, generator)
        p = torch.softmax(-torch.cdist(e, centroids) / TAU, dim=1)
        dice, focal = dice_focal(p, F.one_hot(labels, centroids.shape[0]).to(p.dtype))
        dices.append(dice)
        focals.append(focal)
    return torch.stack(dices).mean(), torch.stack(focals).mean()


def dice_focal(p, one_hot):
    """Dice (mean over the instances present) and focal (γ = 2) losses of assignment probabilities
    p [N,K] against one-hot labels [N,K]."""
    intersection = (p * one_hot).sum(0)
    present = one_hot.sum(0) > 0
    dice = (1 - 2 * intersection / (p.sum(0) + one_hot.sum(0)).clamp_min(1e-6))[present].mean()
    p_true = (p * one_hot).sum(1).clamp(1e-6, 1.0)
    focal = (-(1 - p_true) ** 2 * p_true.log()).mean()
    return dice, focal


def vote_loss(votes, points, depth, instance, room_target=None, box_centres=None):
    """Centre-vote supervision (not in the paper; the votes head is this project's): votes [B,V,3,h,w]
    at half resolution, points [B,V,3,H,W] (the model's scaled world XYZ input), depth [B,V,H,W] and
    instance [B,V,H,W] at full resolution. Each object's target is the mean of its valid points over
    the window's views; the loss is ‖vote − target‖ averaged per object, then over objects, on
    half-resolution pixels whose 2×2 block is one object. By default the room gets no target (its
    centroid lies among the objects'); with `room_target` (3 values) its pixels vote for that
    point and the room counts as one more object in the mean. With `box_centres` ([B,V,3,H,W], per
    pixel its object's box centre in the points' frame, gf.data.box_centre_map) an object's target is
    its box's centre instead of its visible points' centroid."""
    losses = []
    for b in range(votes.shape[0]):
        labels = instance[b]
        valid = depth[b] > 0
        blocks = [labels[:, dy::2, dx::2] for dy in (0, 1) for dx in (0, 1)]
        pure = (blocks[0] == blocks[1]) & (blocks[0] == blocks[2]) & (blocks[0] == blocks[3])
        pure &= F.avg_pool2d(valid.float()[:, None], 2)[:, 0] == 1.0
        half = blocks[0]
        vote = votes[b].permute(0, 2, 3, 1)  # V,h,w,3
        xyz = points[b].permute(0, 2, 3, 1)  # V,H,W,3
        per_object = []
        for k in torch.unique(half[pure & (half > 0)]):
            if box_centres is None:
                target = xyz[(labels == k) & valid].mean(0)
            else:
                # Every pixel of an object holds its box centre: one pixel's will do.
                target = box_centres[b].permute(0, 2, 3, 1)[labels == k][0]
            per_object.append((vote[pure & (half == k)] - target).norm(dim=1).mean())
        room = pure & (half == 0)
        if room_target is not None and room.any():
            target = torch.as_tensor(room_target, dtype=vote.dtype)
            per_object.append((vote[room] - target).norm(dim=1).mean())
        losses.append(torch.stack(per_object).mean() if per_object else votes.sum() * 0.0)
    return torch.stack(losses).mean()


def room_gate_loss(room_logits, instance, balanced=True):
    """Room gate supervision (training only; the gate is this project's, gf.model `room_gate`):
    binary cross-entropy of the room logits [B,V,H,W] against walls and floor (instance 0), batch mean.
    `balanced`: the room's pixels and the objects' weighted equally (the room covers ~3/4 of a
    window); otherwise every pixel alike, which puts the gate's boundary where the fewest pixels are
    wrong (a balanced loss pays 3× more for an object pixel, so objects grow into the room)."""
    losses = []
    for logits, labels in zip(room_logits, instance):
        room = labels == 0
        bce = F.binary_cross_entropy_with_logits(logits, room.to(logits.dtype), reduction='none')
        if balanced:
            parts = [bce[mask].mean() for mask in (room, ~room) if mask.any()]
            losses.append(torch.stack(parts).mean())
        else:
            losses.append(bce.mean())
    return torch.stack(losses).mean()


def depth_loss(predicted, target):
    valid = torch.isfinite(target) & (target > 0)
    if not valid.any():
        return torch.zeros(())
    return (predicted[valid].clamp_min(1e-3).log() - target[valid].log()).abs().mean()



def lift(depth, gaussians, images, k, world_from_camera, count, generator=None):
    """Pick `count` pixel-aligned Gaussians of one window (views of depth [V,H,W], gaussians
    [V,11,H,W]) and lift them to the world as the node does (node/src/recon/gaussians.rs `lift`).
    Returns means, rotations, scales, opacities, colours and the picked flat pixel indices."""
    from .render import quaternion_matrix

    views, height, width = depth.shape
    index = torch.randint(0, views * height * width, (count,), generator=generator)
    view = index // (height * width)
    pixel = index % (height * width)
    y = (pixel // width).to(depth.dtype)
    x = (pixel % width).to(depth.dtype)
    d = depth.reshape(-1)[index]
    kk = k.to(depth.dtype)[view]
    pose = world_from_camera.to(depth.dtype)[view]
    camera = torch.stack([(x - kk[:, 0, 2]) / kk[:, 0, 0] * d, (y - kk[:, 1, 2]) / kk[:, 1, 1] * d, d], dim=-1)
    means = (pose[:, :3, :3] @ camera[:, :, None])[:, :, 0] + pose[:, :3, 3]
    g = gaussians.permute(0, 2, 3, 1).reshape(-1, 11)[index]
    focal = (kk[:, 0, 0] + kk[:, 1, 1]) / 2
    scales = g[:, 1:4] * (d / focal)[:, None]
    rotations = pose[:, :3, :3] @ quaternion_matrix(g[:, 4:8])
    colours = (images.permute(0, 2, 3, 1).reshape(-1, 3)[index] + g[:, 8:11]).clamp(0, 1)
    return means, rotations, scales, g[:, 0], colours, index


def small_intrinsics(k, scale):
    """Intrinsics for an image `scale` times the size (pixel centres at integer coordinates)."""
    out = k.clone()
    out[..., 0, 0] *= scale
    out[..., 1, 1] *= scale
    out[..., 0, 2] = (k[..., 0, 2] + 0.5) * scale - 0.5
    out[..., 1, 2] = (k[..., 1, 2] + 0.5) * scale - 0.5
    return out


def rendered_losses(depth, gaussians, embeddings, batch, count=4096, scale=0.25, generator=None):
    """Rendered terms of ARCHITECTURE.md §5 on the context views: assignment probabilities
    p_gk = softmax_k(−‖e_g − ē_k‖/τ) rendered with dice + focal against the instance masks, rendered
    embeddings pulled to their instance centroid and centroids pushed apart, and a photometric L1.
    Returns (dice, focal, pull, push, photometric), batch means."""
    from .render import render

    terms = []
    for b in range(depth.shape[0]):
        instance = batch['instance'][b]
        views, height, width = instance.shape
        e = F.normalize(embeddings[b].permute(0, 2, 3, 1).reshape(-1, embeddings.shape[2]), dim=1)
        ids, labels = torch.unique(instance.reshape(-1), return_inverse=True)
        k = ids.numel()
        centroids = F.normalize(torch.zeros(k, e.shape[1]).index_add_(0, labels, e), dim=1)
        means, rotations, scales, opacities, colours, index = lift(
            depth[b], gaussians[b], batch['images'][b], batch['k'][b], batch['world_from_camera'][b], count,
            generator)
        probabilities = torch.softmax(-torch.cdist(e[index], centroids) / TAU, dim=1)
        features = torch.cat([probabilities, e[index], colours], dim=1)
        h, w = int(height * scale), int(width * scale)
        kk = small_intrinsics(batch['k'][b].to(depth.dtype), scale)
        dice, focal, pull, push, photo = [], [], [], [], []
        for v in range(views):
            out, alpha = render(means, rotations, scales, opacities, features, kk[v],
                                batch['world_from_camera'][b][v].to(depth.dtype), h, w)
            # Ground truth at the render's resolution (nearest pixel centre).
            rows = ((torch.arange(h) + 0.5) / scale).long().clamp(max=height - 1)
            cols = ((torch.arange(w) + 0.5) / scale).long().clamp(max=width - 1)
            target = labels.reshape(views, height, width)[v][rows][:, cols]
            covered = alpha > 0.5
            if covered.sum() < 4:
                continue
            p = out[..., :k] / alpha.clamp_min(1e-6)[..., None]
            one_hot = F.one_hot(target, k).to(p.dtype)
            view_dice, view_focal = dice_focal(p[covered], one_hot[covered])
            dice.append(view_dice)
            focal.append(view_focal)
            rendered_e = F.normalize(out[..., k:k + e.shape[1]][covered], dim=1)
            pixel_labels = target[covered]
            pull.append((rendered_e - centroids[pixel_labels]).norm(dim=1).mean())
            present_ids, present_labels = torch.unique(pixel_labels, return_inverse=True)
            if present_ids.numel() > 1:
                rendered_centroids = F.normalize(
                    torch.zeros(present_ids.numel(), e.shape[1]).index_add_(0, present_labels, rendered_e), dim=1)
                distances = torch.cdist(rendered_centroids, rendered_centroids)
                off = ~torch.eye(present_ids.numel(), dtype=torch.bool)
                push.append(F.relu(MARGIN - distances[off]).mean())
            image = batch['images'][b][v][:, rows][:, :, cols].permute(1, 2, 0)
            rendered_colour = out[..., k + e.shape[1]:] / alpha.clamp_min(1e-6)[..., None]
            photo.append((rendered_colour - image).abs()[covered].mean())
        mean = lambda xs: torch.stack(xs).mean() if xs else torch.zeros(())  # noqa: E731
        terms.append(torch.stack([mean(dice), mean(focal), mean(pull), mean(push), mean(photo)]))
    return tuple(torch.stack(terms).mean(0))
