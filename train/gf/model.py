"""GroupForward-mini: the paper's feed-forward design at small scale, in two input modes.

A shared per-view convolutional encoder, cross-view attention over all views' bottleneck tokens, a
U-Net decoder, and three heads (ARCHITECTURE.md §5 contract):
- depth [B,V,H,W] in metres (exp of the head, so always positive);
- gaussians [B,V,11,H,W] = opacity (sigmoid), scale (3, softplus, pixels at unit depth), rotation (4,
  unit quaternion xyzw in the camera frame), colour residual (3, 0.2·tanh);
- embeddings [B,V,8,H,W]: from multi-scale decoder features, the predicted (log) depth and the raw
  input (colour; world XYZ in RGB-D mode), computed at half resolution and upsampled. Optionally
  (`refine`, off: it lowered the grouped ARI in both modes, see the README) one full-resolution
  convolution over the finest decoder features sharpens them at boundaries.
  With `centre_votes` (RGB-D mode) the half-resolution head predicts, per pixel, an offset from its
  world point to a vote for its object's centre plus free features, and a per-pixel MLP over Fourier
  features of the vote and the free features gives the embedding: every pixel of one object, in
  every view, should vote for the same 3D point, so consistency across views needs no learned
  appearance correspondence (spatial embeddings, Neven et al. 2019, lifted to 3D). Same losses.
  With `room_gate` the head also predicts, per pixel, a logit that the pixel is wall or floor, and
  the embedding becomes g·r + (1 − g)·ê with g = sigmoid(logit), ê the unit embedding and r a learned
  unit vector: the room (one instance spread over every view) shrinks towards one point (the node's
  centroid merge joins the density modes HDBSCAN still finds in it), and telling a white cabinet
  from the white wall behind it is a per-pixel classification with its own loss
  (gf.losses.room_gate_loss) rather than a margin. With `sharp_gate` a small full-resolution head
  over the finest decoder features and the raw input corrects the upsampled room logit: the
  half-resolution gate lets objects grow a pixel or two into the room, and those room pixels are
  most of what the room-gate model's grouping gets wrong (README, Training). An experiment: it
  removed most of that bleed but did not beat the half-resolution gate's ARI in one seed.
  With `guided_upsampling` (σ_points, σ_colour) the half-resolution room logit and embeddings are
  brought to full resolution by joint bilateral upsampling (Kopf et al. 2007) instead of bilinear:
  each full-resolution pixel averages the 3×3 half-resolution cells around it, weighted by how close
  each cell's mean input (world XYZ in RGB-D mode, colour) is to the pixel's own, so a pixel on an
  object's silhouette takes its value from the object's cells, not from the wall's. It has no weights
  and can be switched on for a model trained without it (`enable_guided_upsampling`).

RGB-D mode (the node's default) takes `points` (world XYZ from sensor depth, centred and scaled as
gf.data.world_points does) next to `images`; RGB mode (the paper's setting) takes images only and the
depth head predicts geometry. Posed RGB mode (`posed`, an experiment) also takes the views'
intrinsics and TF poses (gf.data.world_cameras): a plane-sweep matching cost over the window's views
(`plane_sweep_cost`, as MVSplat's cost volume) joins the decoder at half resolution, so depth can be
triangulated instead of guessed from one view's appearance; with `sweep_depth` the sweep's own
depth (soft-argmin over the planes) and confidence join it too, and an auxiliary depth loss on that
depth trains the matching features directly. Only plain ops (conv, group norm, matmul attention,
interpolation, sin / cos, grid sampling) so the legacy ONNX exporter handles a dynamic number of views.
"""

import math

import torch
from torch import nn
from torch.nn import functional as F

from .data import POINTS_SCALE  # the camera input's world units


# Centre votes: free features next to the 3D vote, and Fourier frequencies 2^i·π of the vote (points are
# scaled to about unit range, so objects 0.3 m apart differ by ~0.1 and the top frequency resolves that).
VOTE_FEATURES = 13
VOTE_FREQUENCIES = 4

# Posed RGB mode's plane sweep: depth planes evenly spaced in inverse depth over the sim's rooms (metres),
# matched with unit features of this many channels at half resolution, where neighbouring views of a
# window (~0.2 m apart, focal 64 px) differ by 1–6 px at room depths.
SWEEP_PLANES = 24
SWEEP_NEAR = 0.4
SWEEP_FAR = 10.0
SWEEP_FEATURES = 16


def unit_vectors(x, dim=1, eps=1e-12):
    """x / max(‖x‖, eps) along `dim`, as F.normalize, from a sum of squares: PyTorch's CPU norm over a
    non-innermost dimension is ~40× slower (18 ms against 0.4 ms for a batch's [8,8,96,128] embeddings),
    which made the norms an eighth of a training step."""
    return x / (x * x).sum(dim, keepdim=True).clamp_min(eps * eps).sqrt()


def sweep_inverse_depths():
    """The plane sweep's planes [D] as inverse depths (1/m), nearest first."""
    return torch.linspace(1.0 / SWEEP_NEAR, 1.0 / SWEEP_FAR, SWEEP_PLANES)


def plane_sweep_cost(features, intrinsics, world_from_camera, full_height, full_width):
    """Matching cost [B,V,D,h,w] of a window's views: for every pixel of every view and each depth plane,
    the mean over the other views of the dot product between its unit feature and the feature (bilinear)
    where that 3D point projects; views where it falls behind the camera or outside the image do not
    count (0 where no view sees it). features [B,V,C,h,w] at a stride of the full_height × full_width
    images; intrinsics [B,V,3,3] in full-resolution pixels; world_from_camera [B,V,4,4] in the points'
    frame (translation in units of POINTS_SCALE metres). Matrix products and grid sampling only, for
    ONNX and a dynamic number of views."""
    b, v, c, h, w = features.shape
    stride_y, stride_x = full_height / h, full_width / w
    distances = (1.0 / sweep_inverse_depths()) / POINTS_SCALE  # [D], z in world units
    ys = (torch.arange(h, dtype=torch.float32) + 0.5) * stride_y - 0.5
    xs = (torch.arange(w, dtype=torch.float32) + 0.5) * stride_x - 0.5
    fx, fy = intrinsics[:, :, 0, 0, None, None], intrinsics[:, :, 1, 1, None, None]
    cx, cy = intrinsics[:, :, 0, 2, None, None], intrinsics[:, :, 1, 2, None, None]
    ray_x = (xs[None, None, None, :] - cx) / fx  # [B,V,1,w]
    ray_y = (ys[None, None, :, None] - cy) / fy  # [B,V,h,1]
    rays = torch.stack([ray_x.expand(-1, -1, h, -1), ray_y.expand(-1, -1, -1, w),
                        torch.ones_like(ray_x).expand(-1, -1, h, w)], dim=2).reshape(b, v, 3, h * w)
    rotation, translation = world_from_camera[:, :, :3, :3], world_from_camera[:, :, :3, 3]
    world_rays = rotation @ rays  # [B,Vi,3,hw]
    points = translation[:, :, None, :, None] + distances[None, None, :, None, None] * world_rays[:, :, None]
    # Into every view j: camera_j = R_jᵀ (X − t_j), for all source views i and planes at once.
    relative = points[:, None] - translation[:, :, None, None, :, None]  # [B,Vj,Vi,D,3,hw]
    camera = rotation.transpose(-1, -2)[:, :, None, None] @ relative
    z = camera[:, :, :, :, 2]
    safe_z = z.clamp_min(1e-3)
    # View j's intrinsics over [B,Vj,Vi,D,hw].
    u = fx[..., None] * camera[:, :, :, :, 0] / safe_z + cx[..., None]
    v_ = fy[..., None] * camera[:, :, :, :, 1] / safe_z + cy[..., None]
    grid_x = (u + 0.5) / full_width * 2.0 - 1.0
    grid_y = (v_ + 0.5) / full_height * 2.0 - 1.0
    seen = (z > 1e-2) & (grid_x.abs() <= 1.0) & (grid_y.abs() <= 1.0)
    others = 1.0 - torch.eye(v, dtype=features.dtype)  # a view does not match itself
    weight = seen.to(features.dtype) * others[None, :, :, None, None]  # [B,Vj,Vi,D,hw]
    grid = torch.stack([grid_x, grid_y], dim=-1).reshape(b * v, v * SWEEP_PLANES * h, w, 2)
    sampled = F.grid_sample(features.reshape(b * v, c, h, w), grid, mode='bilinear', padding_mode='zeros',
                            align_corners=False).reshape(b, v, c, v, SWEEP_PLANES, h * w)
    similarity = (sampled * features.transpose(1, 2).reshape(b, 1, c, v, 1, h * w)).sum(2)  # [B,Vj,Vi,D,hw]
    cost = (similarity * weight).sum(1) / weight.sum(1).clamp_min(1.0)
    return cost.reshape(b, v, SWEEP_PLANES, h, w)


def batch_inputs(batch, names):
    """The named contract inputs (GroupForwardMini.input_names) from a batch of gf.data.SimDataset items,
    as forward()'s keyword arguments."""
    keys = {'images': 'images', 'points': 'points', 'intrinsics': 'k', 'world_from_camera': 'cameras'}
    return {name: batch[keys[name]].float() for name in names}


def example_inputs(names, views, generator, height=96, width=128):
    """The named contract inputs, random: images and points, and cameras like the sim's (90° field of
    view, views 0.2 m apart along a line, turned up to ±0.3 rad), posed in the points' frame; for
    checking an exported graph against the model."""
    images = torch.rand(1, views, 3, height, width, generator=generator)
    points = torch.randn(1, views, 3, height, width, generator=generator) * 0.5
    k = torch.tensor([[width / 2, 0.0, (width - 1) / 2], [0.0, width / 2, (height - 1) / 2], [0.0, 0.0, 1.0]])
    intrinsics = k.expand(1, views, 3, 3).contiguous()
    cameras = torch.eye(4).repeat(1, views, 1, 1)
    for i, yaw in enumerate((torch.rand(views, generator=generator) - 0.5) * 0.6):
        c, s = torch.cos(yaw), torch.sin(yaw)
        cameras[0, i, :3, :3] = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        cameras[0, i, 0, 3] = (i - (views - 1) / 2) * 0.2 / POINTS_SCALE
    every = {'images': images, 'points': points, 'intrinsics': intrinsics, 'world_from_camera': cameras}
    return {name: every[name] for name in names}


def cpu_session(model, threads=None):
    """An onnxruntime CPU session of an exported model (a path, or serialized bytes), on `threads`
    intra-op threads (onnxruntime's default when None)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    if threads is not None:
        options.intra_op_num_threads = threads
    model = model if isinstance(model, bytes) else str(model)
    return ort.InferenceSession(model, options, providers=['CPUExecutionProvider'])


def onnx_parity(model, session, feed, outputs=('depth', 'gaussians', 'embeddings')):
    """The largest difference between `model`'s outputs and an onnxruntime `session`'s on `feed`, as a
    share of each output's largest magnitude (at least 1): float32 rounding grows with the values
    (embeddings reach ~35). A model with one output (the semantic model) names it alone."""
    with torch.no_grad():
        expected = model(**feed)
    expected = (expected,) if torch.is_tensor(expected) else expected
    got = session.run(list(outputs), {k: t.numpy() for k, t in feed.items()})
    return max(float((e - torch.from_numpy(g)).abs().max()) / max(1.0, float(e.abs().max()))
               for e, g in zip(expected, got))


def block(cin, cout, stride=1):
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride=stride, padding=1),
        nn.GroupNorm(8, cout),
        nn.GELU(),
        nn.Conv2d(cout, cout, 3, padding=1),
        nn.GroupNorm(8, cout),
        nn.GELU(),
    )


class CrossViewAttention(nn.Module):
    """Pre-norm transformer layer over the tokens of all views of a window."""

    def __init__(self, dim, heads=4, hidden=256):
        super().__init__()
        self.heads = heads
        self.norm1 = nn.LayerNorm(dim)
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)
        self.norm2 = nn.LayerNorm(dim)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))

    def forward(self, x):  # x: [B, T, D]
        b, t, d = x.shape
        h = self.heads
        q, k, v = self.qkv(self.norm1(x)).reshape(b, t, 3, h, d // h).permute(2, 0, 3, 1, 4)
        attention = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(d // h), dim=-1)
        y = (attention @ v).transpose(1, 2).reshape(b, t, d)
        x = x + self.proj(y)
        return x + self.mlp(self.norm2(x))


def positional_encoding(height, width, dim, span=None):
    """2D sinusoidal encoding [dim, height, width]: half the channels for rows, half for columns.
    `span` (rows, columns): the grid the encoding was trained on, which a finer grid samples in
    between (a model exported at a larger input keeps the positions it learned; None: the grid
    itself)."""
    span_rows, span_columns = span or (height, width)
    quarter = dim // 4
    frequencies = torch.exp(torch.arange(quarter) * (-math.log(100.0) / quarter))
    ys = (torch.arange(height).float() * (span_rows / height))[:, None] * frequencies[None]
    xs = (torch.arange(width).float() * (span_columns / width))[:, None] * frequencies[None]
    rows = torch.cat([ys.sin(), ys.cos()], dim=1).T[:, :, None].expand(-1, -1, width)
    cols = torch.cat([xs.sin(), xs.cos()], dim=1).T[:, None, :].expand(-1, height, -1)
    return torch.cat([rows, cols], dim=0)


class GroupForwardMini(nn.Module):
    def __init__(self, mode='rgbd', height=96, width=128, embedding_dim=8, width_mult=1.0, refine=False,
                 centre_votes=None, room_gate=False, sharp_gate=False, posed=False, sweep_depth=False,
                 guided_upsampling=None):
        super().__init__()
        assert not posed or mode == 'rgb', 'the posed plane sweep is for RGB mode (RGB-D has points)'
        assert mode in ('rgbd', 'rgb')
        assert room_gate or not sharp_gate, 'the sharp gate refines the room gate'
        self.mode = mode
        self.refine = refine
        self.room_gate = room_gate
        self.sharp_gate = sharp_gate
        self.posed = posed
        assert posed or not sweep_depth, 'the sweep depth comes from the posed plane sweep'
        self.sweep_depth = sweep_depth
        self.centre_votes = (mode == 'rgbd') if centre_votes is None else centre_votes
        assert not (self.centre_votes and mode != 'rgbd'), 'centre votes need world points (RGB-D mode)'
        self.embedding_dim = embedding_dim
        c = [int(32 * width_mult), int(64 * width_mult), int(96 * width_mult), int(128 * width_mult)]
        cin = 6 if mode == 'rgbd' else 3
        self.enc1 = block(cin, c[0], stride=2)
        self.enc2 = block(c[0], c[1], stride=2)
        self.enc3 = block(c[1], c[2], stride=2)
        self.enc4 = block(c[2], c[3], stride=2)
        self.trained_size = (height, width)
        self.register_buffer('position', positional_encoding(height // 16, width // 16, c[3]), persistent=False)
        self.attention = nn.ModuleList([CrossViewAttention(c[3]) for _ in range(2)])
        self.dec3 = block(c[3] + c[2], c[2])
        self.dec2 = block(c[2] + c[1], c[1])
        self.dec1 = block(c[1] + c[0] + (SWEEP_PLANES if posed else 0) + (2 if sweep_depth else 0), c[0])
        if posed:
            # Matching features for the plane sweep, from the first encoder level (half resolution).
            self.sweep_features = nn.Conv2d(c[0], SWEEP_FEATURES, 1)
        if sweep_depth:
            # Softmax sharpness of the matching cost over the planes (costs are cosines in [-1, 1]).
            self.sweep_temperature = nn.Parameter(torch.tensor(10.0))
        # Full resolution is the expensive level: one convolution there.
        self.dec0 = nn.Sequential(nn.Conv2d(c[0] + cin, c[0], 3, padding=1), nn.GroupNorm(8, c[0]), nn.GELU())
        self.depth_head = nn.Conv2d(c[0], 1, 3, padding=1)
        self.gaussian_head = nn.Conv2d(c[0], 11, 3, padding=1)
        # At half resolution (a quarter of the cost), upsampled bilinearly.
        self.instance_head = nn.Sequential(
            nn.Conv2d(c[0] + c[0] + c[1] + 1 + cin, 64, 3, padding=1),
            nn.GELU(),
            nn.Conv2d(64, 64, 3, padding=1),
            nn.GELU(),
            nn.Conv2d(64, (VOTE_FEATURES + 3 if self.centre_votes else embedding_dim) + int(room_gate), 1),
        )
        if room_gate:
            self.instance_room_vector = nn.Parameter(F.normalize(torch.randn(embedding_dim), dim=0))
        if self.centre_votes:
            self.instance_vote_mlp = nn.Sequential(
                nn.Conv2d(3 * (1 + 2 * VOTE_FREQUENCIES) + VOTE_FEATURES, 64, 1),
                nn.GELU(),
                nn.Conv2d(64, embedding_dim, 1),
            )
        if refine:
            # Starts as the identity on the upsampled embeddings.
            self.instance_refine = nn.Conv2d(c[0] + embedding_dim, embedding_dim, 3, padding=1)
            nn.init.zeros_(self.instance_refine.weight)
            nn.init.zeros_(self.instance_refine.bias)
        # Rooms are metres deep: start the depth head near 2.5 m.
        nn.init.zeros_(self.depth_head.weight)
        nn.init.constant_(self.depth_head.bias, math.log(2.5))
        if sharp_gate:
            # A full-resolution correction of the upsampled room logit over the finest features and the
            # raw input, starting at zero and created last (the other layers draw the same initial
            # weights as without it): the half-resolution logit can only interpolate across 2×2 blocks.
            self.instance_room_refine = nn.Sequential(
                nn.Conv2d(c[0] + cin + 1, 16, 3, padding=1), nn.GELU(), nn.Conv2d(16, 1, 3, padding=1))
            nn.init.zeros_(self.instance_room_refine[2].weight)
            nn.init.zeros_(self.instance_room_refine[2].bias)
        if guided_upsampling is not None:
            self.enable_guided_upsampling(*guided_upsampling)

    def set_input_size(self, height, width):
        """Take `height` × `width` inputs from now on (both multiples of 16, the trained aspect):
        the convolutions are size-free, and the views' tokens sample the positions learned on the
        trained grid in between, so a finer input keeps them. Small objects cover more pixels at a
        larger input (the camera's 320 × 240 resampled to 128 × 96 leaves a lamp a few). At the
        trained size the positions are the trained ones."""
        trained_height, trained_width = self.trained_size
        if height % 16 or width % 16:
            raise ValueError(f'{width} x {height}: both sides must be multiples of 16')
        if height * trained_width != width * trained_height:
            raise ValueError(f'{width} x {height}: not the trained {trained_width} x {trained_height} aspect')
        span = (trained_height // 16, trained_width // 16)
        self.position = positional_encoding(height // 16, width // 16, self.position.shape[0], span).to(self.position)

    def enable_guided_upsampling(self, sigma_points, sigma_colour):
        """Upsample the instance head by joint bilateral upsampling from now on (range kernels σ_points
        on the points input, in its scaled units, and σ_colour on colour in [0, 1]); kept in the
        state dict, so a checkpoint or an export carries it."""
        assert sigma_points > 0 and sigma_colour > 0, 'both range kernels need a positive width'
        self.register_buffer('instance_guide_sigmas', torch.tensor([sigma_points, sigma_colour]))

    @property
    def guided_upsampling(self):
        return hasattr(self, 'instance_guide_sigmas')

    def upsample_instance(self, half, weights):
        """The half-resolution instance output `half` [N,C,H/2,W/2] at full resolution: bilinear, or
        by joint bilateral upsampling with `weights` (bilateral_weights of this forward's input)."""
        if weights is None:
            return F.interpolate(half, scale_factor=2.0, mode='bilinear', align_corners=False)
        return joint_bilateral_upsample(half, weights)

    def reconstruction_parameters(self):
        return [p for name, p in self.named_parameters() if not name.startswith('instance_')]

    def instance_parameters(self):
        return [p for name, p in self.named_parameters() if name.startswith('instance_')]

    @classmethod
    def for_parameter_names(cls, names, mode):
        """An untrained model with the architecture whose state dict has (at least) these names."""
        names = set(names)
        prefixed = lambda prefix: any(name.startswith(prefix) for name in names)  # noqa: E731
        return cls(mode=mode, refine=prefixed('instance_refine'), centre_votes=prefixed('instance_vote_mlp'),
                   room_gate='instance_room_vector' in names, sharp_gate=prefixed('instance_room_refine'),
                   posed='sweep_features.weight' in names, sweep_depth='sweep_temperature' in names,
                   guided_upsampling=(1.0, 1.0) if 'instance_guide_sigmas' in names else None)

    @classmethod
    def from_state_dict(cls, state, mode):
        """A model with the architecture the checkpoint `state` was trained with, its weights loaded."""
        model = cls.for_parameter_names(state, mode)
        model.load_state_dict(state)
        return model

    @torch.no_grad()
    def shift_room_logit(self, bias):
        """Add `bias` to the room gate's logit everywhere (a calibration chosen after training on the
        selection windows; positive keeps more boundary pixels in the room)."""
        assert self.room_gate, 'no room gate to calibrate'
        self.get_parameter(room_logit_bias_name(self.sharp_gate))[-1] += bias

    def input_names(self):
        """The exported contract's inputs, in order: images, and points (RGB-D) or intrinsics and
        world_from_camera (posed RGB)."""
        if self.mode == 'rgbd':
            return ['images', 'points']
        return ['images', 'intrinsics', 'world_from_camera'] if self.posed else ['images']

    def inputs(self, batch):
        """forward()'s keyword inputs from a batch of gf.data.SimDataset items."""
        return batch_inputs(batch, self.input_names())

    def forward(self, images, points=None, intrinsics=None, world_from_camera=None):
        """(depth, gaussians, embeddings): the exported contract."""
        return self.forward_with_votes(images, points, intrinsics, world_from_camera)[:3]

    def forward_with_votes(self, images, points=None, intrinsics=None, world_from_camera=None):
        """(depth, gaussians, embeddings, votes): also the half-resolution centre votes [B,V,3,H/2,W/2]
        (None without `centre_votes`), for the training-only vote loss."""
        return self.forward_training(images, points, intrinsics, world_from_camera)[:4]

    def forward_training(self, images, points=None, intrinsics=None, world_from_camera=None,
                         instance_gradient=True):
        """(depth, gaussians, embeddings, votes, room logits, sweep depth): also the full-resolution
        room logits [B,V,H,W] (None without `room_gate`), for the training-only room loss, and the
        plane sweep's own depth [B,V,H/2,W/2] (None without `sweep_depth`) for its auxiliary loss.
        With `instance_gradient` False the instance head reads the decoder's features and the depth
        detached, so the instance losses train that head alone and never move the depth path."""
        b, v = images.shape[0], images.shape[1]
        x = images.flatten(0, 1)
        if self.mode == 'rgbd':
            x = torch.cat([x, points.flatten(0, 1)], dim=1)
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        e3 = self.enc3(e2)
        e4 = self.enc4(e3)
        # Cross-view fusion: every token of every view attends to all tokens of the window.
        n, d, h, w = e4.shape
        tokens = (e4 + self.position).reshape(b, v, d, h * w).permute(0, 1, 3, 2).reshape(b, v * h * w, d)
        for layer in self.attention:
            tokens = layer(tokens)
        e4 = tokens.reshape(b, v, h * w, d).permute(0, 1, 3, 2).reshape(n, d, h, w)
        up = lambda t: F.interpolate(t, scale_factor=2.0, mode='nearest')  # noqa: E731
        d3 = self.dec3(torch.cat([up(e4), e3], dim=1))
        d2 = self.dec2(torch.cat([up(d3), e2], dim=1))
        skip = [up(d2), e1]
        sweep_depth = None
        if self.posed:
            # Triangulation the attention at 1/16 resolution cannot do: where each pixel's features
            # match the other views' along its ray, from the TF poses.
            matching = unit_vectors(self.sweep_features(e1))
            cost = plane_sweep_cost(matching.reshape(b, v, *matching.shape[1:]), intrinsics, world_from_camera,
                                    images.shape[-2], images.shape[-1]).flatten(0, 1)
            skip.append(cost)
            if self.sweep_depth:
                # The sweep's own depth (expected inverse depth over the planes) and its confidence, handed
                # to the decoder ready to copy: the raw costs alone were barely used (README, Training).
                probability = torch.softmax(cost * self.sweep_temperature, dim=1)
                inverse = sweep_inverse_depths().reshape(1, -1, 1, 1)
                sweep_log_depth = -torch.log((probability * inverse).sum(1, keepdim=True))
                skip += [sweep_log_depth, probability.max(1, keepdim=True)[0]]
                sweep_depth = torch.exp(sweep_log_depth[:, 0]).reshape(b, v, *sweep_log_depth.shape[2:])
        d1 = self.dec1(torch.cat(skip, dim=1))
        d0 = self.dec0(torch.cat([up(d1), x], dim=1))
        log_depth = self.depth_head(d0)
        depth = torch.exp(log_depth.clamp(-5.0, 5.0))
        raw = self.gaussian_head(d0)
        opacity = torch.sigmoid(raw[:, 0:1])
        scale = F.softplus(raw[:, 1:4]) + 0.1
        rotation = raw[:, 4:8] + torch.tensor([0.0, 0.0, 0.0, 1.0]).reshape(1, 4, 1, 1)
        rotation = unit_vectors(rotation, eps=1e-6)
        residual = 0.2 * torch.tanh(raw[:, 8:11])
        gaussians = torch.cat([opacity, scale, rotation, residual], dim=1)
        down = lambda t: F.avg_pool2d(t, 2)  # noqa: E731
        # The raw input (colour, and world XYZ in RGB-D mode) goes straight in as well: instances are
        # compact in 3D, and the decoder's features are shaped by the depth loss first (curriculum).
        x_half = down(x)
        features = torch.cat([down(d0), d1, up(d2), down(log_depth), x_half], dim=1)
        if not instance_gradient:
            features = features.detach()
        embeddings = self.instance_head(features)
        upsampling = (bilateral_weights(x, self.instance_guide_sigmas[0], self.instance_guide_sigmas[1])
                      if self.guided_upsampling else None)
        room_logit = None
        if self.room_gate:
            room_logit = self.upsample_instance(embeddings[:, -1:], upsampling)
            embeddings = embeddings[:, :-1]
            if self.sharp_gate:
                room_logit = room_logit + self.instance_room_refine(torch.cat([d0, x, room_logit], dim=1))
        vote = None
        if self.centre_votes:
            vote = x_half[:, 3:6] + embeddings[:, :3]
            scaled = torch.cat([vote * (2.0 ** i) * math.pi for i in range(VOTE_FREQUENCIES)], dim=1)
            embeddings = self.instance_vote_mlp(torch.cat([vote, scaled.sin(), scaled.cos(), embeddings[:, 3:]], dim=1))
        embeddings = self.upsample_instance(embeddings, upsampling)
        if self.refine:
            embeddings = embeddings + self.instance_refine(torch.cat([d0, embeddings], dim=1))
        if self.room_gate:
            unit = unit_vectors(embeddings, eps=1e-6)
            room = self.instance_room_vector / self.instance_room_vector.norm().clamp_min(1e-6)
            gate = torch.sigmoid(room_logit)
            embeddings = gate * room.reshape(1, -1, 1, 1) + (1 - gate) * unit
        shape = lambda t: t.reshape(b, v, *t.shape[1:])  # noqa: E731
        return (shape(depth[:, 0]), shape(gaussians), shape(embeddings), None if vote is None else shape(vote),
                None if room_logit is None else shape(room_logit[:, 0]), sweep_depth)


def bilateral_weights(guide, sigma_points, sigma_colour):
    """Joint bilateral upsampling weights [9,N,1,H,W] of the 3×3 half-resolution cells around each pixel
    of `guide` [N,3 or 6,H,W]: softmax over the cells of −d²/2 − ‖g − ḡ‖²/2σ², with d the distance from
    the pixel's centre to the cell's (in cells), g the pixel's guide (colour, σ_colour; points,
    σ_points) and ḡ the cell's mean guide (the 2×2 pixels it covers). Borders repeat the edge cells.
    They depend on the guide alone, so one set serves every output upsampled from the same views."""
    height, width = guide.shape[-2], guide.shape[-1]
    cell_guide = F.interpolate(F.avg_pool2d(guide, 2), scale_factor=2.0, mode='nearest')
    # A pixel's centre lies a quarter cell from its cell's centre: towards -1 for even rows/columns.
    row_offset = (torch.arange(height) % 2 - 0.5).reshape(1, 1, -1, 1) * 0.5
    column_offset = (torch.arange(width) % 2 - 0.5).reshape(1, 1, 1, -1) * 0.5
    sigmas = [sigma_colour] * 3 + [sigma_points] * (guide.shape[1] - 3)
    inverse_variance = torch.stack([1.0 / (2.0 * s ** 2) for s in sigmas]).reshape(1, -1, 1, 1)
    padded_guide = F.pad(cell_guide, (2, 2, 2, 2), mode='replicate')
    exponents = []
    for rows, columns, dy, dx in _neighbour_cells(height, width):
        spatial = ((dy - row_offset) ** 2 + (dx - column_offset) ** 2) / 2.0
        difference = guide - padded_guide[..., rows, columns]
        exponents.append(-spatial - (difference ** 2 * inverse_variance).sum(1, keepdim=True))
    # A softmax over the nine cells: the largest weight is 1 however narrow the kernels.
    return torch.softmax(torch.stack(exponents), dim=0)


def joint_bilateral_upsample(half, weights):
    """`half` [N,C,H/2,W/2] at full resolution [N,C,H,W]: each pixel the mean of the 3×3 cells around it
    under `weights` (bilateral_weights)."""
    height, width = weights.shape[-2], weights.shape[-1]
    padded = F.pad(F.interpolate(half, scale_factor=2.0, mode='nearest'), (2, 2, 2, 2), mode='replicate')
    neighbours = torch.stack([padded[..., rows, columns] for rows, columns, _, _ in _neighbour_cells(height, width)])
    return (weights * neighbours).sum(0)


def _neighbour_cells(height, width):
    """(rows, columns, dy, dx) of the 3×3 cells around each pixel, as slices of a nearest-upsampled map
    padded by 2 pixels (one cell) on every side."""
    return [(slice(2 + 2 * dy, 2 + 2 * dy + height), slice(2 + 2 * dx, 2 + 2 * dx + width), dy, dx)
            for dy in (-1, 0, 1) for dx in (-1, 0, 1)]


def room_logit_bias_name(sharp_gate):
    """The parameter (also the ONNX initializer) whose last element is the bias of the final room
    logit: the full-resolution correction's output with `sharp_gate`, else the instance head's
    last channel."""
    return 'instance_room_refine.2.bias' if sharp_gate else 'instance_head.4.bias'


def parameter_count(model):
    return sum(p.numel() for p in model.parameters())
