"""Loader for the simulator's training datasets (`groupforward sim dataset`).

Layout (sim/src/dataset.rs): <root>/dataset.json, and per scene <root>/<scene>/cameras.json with
view_NN_{rgb,depth,instance,class}.png. Depth PNGs are millimetres (0 = invalid); instance 0 and class
0 are the room (walls and floor), kept as one background instance in the losses.

RGB-D inputs are built exactly as the node builds them (node/src/model/reconstruction.rs): world XYZ
back-projected from depth with each view's pose, centred on the window's mean camera centre and divided
by `points_scale`; invalid depth (0, NaN) is first filled from its farthest valid 4-neighbour, pass after
pass (`fill_invalid_depth`, the node's `fill_invalid_depth`), and only a view without any valid depth
becomes the centre (0). The posed RGB model takes the views'
intrinsics (`k`) and their poses in that same frame (`world_cameras`) instead of points.
"""

import json
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from .depth_fill import fill_invalid_depth

POINTS_SCALE = 3.0


def load_png(path):
    return np.asarray(Image.open(path))


class SimDataset(torch.utils.data.Dataset):
    """One item = one scene's window of V views."""

    def __init__(self, root, mode='rgbd', pseudo_labels=None, box_centres=False):
        self.root = Path(root)
        # Instance ids from train/make_pseudo_labels.py instead of the ground truth.
        self.pseudo_labels = Path(pseudo_labels) if pseudo_labels else None
        if box_centres and self.pseudo_labels:
            raise ValueError('box centres need the ground-truth instance ids, not pseudo labels')
        # Per pixel, the centre of its object's whole box (`box_centre_map`): the vote target that
        # every piece of an object agrees on, however little of it a window sees.
        self.box_centres = box_centres
        self.manifest = json.loads((self.root / 'dataset.json').read_text())
        self.scenes = list(self.manifest['scenes'])
        self.mode = mode
        self.split = self.manifest['split']

    def __len__(self):
        return len(self.scenes)

    @property
    def window_size(self):
        """(height, width) of the views (`sim dataset --width --height`; 128 x 96 where the manifest
        predates the field)."""
        return self.manifest.get('height', 96), self.manifest.get('width', 128)

    def objects(self, index):
        """The scene's objects (instance id, class, colour, world bounds) from its cameras.json."""
        return json.loads((self.root / self.scenes[index] / 'cameras.json').read_text())['objects']

    def __getitem__(self, index):
        scene = self.root / self.scenes[index]
        cameras = json.loads((scene / 'cameras.json').read_text())
        rgb, depth, instance, klass, intrinsics, poses = [], [], [], [], [], []
        for view in cameras['views']:
            rgb.append(load_png(scene / view['rgb']).astype(np.float32) / 255.0)
            depth.append(load_png(scene / view['depth']).astype(np.float32) / 1000.0)
            instance.append(load_png(scene / view['instance']).astype(np.int64))
            klass.append(load_png(scene / view['class']).astype(np.int64))
            intrinsics.append(np.asarray(view['k'], np.float64).reshape(3, 3))
            poses.append(np.asarray(view['world_from_camera'], np.float64))
        rgb = np.stack(rgb).transpose(0, 3, 1, 2)  # V,3,H,W
        depth = np.stack(depth)  # V,H,W
        item = {
            'images': torch.from_numpy(np.ascontiguousarray(rgb)),
            'depth': torch.from_numpy(depth),
            'instance': torch.from_numpy(
                np.load(self.pseudo_labels / f'{self.scenes[index]}.npy').astype(np.int64) if self.pseudo_labels
                else np.stack(instance)),
            'class': torch.from_numpy(np.stack(klass)),
            'k': torch.from_numpy(np.stack(intrinsics)),
            'world_from_camera': torch.from_numpy(np.stack(poses)),
        }
        item['points'] = torch.from_numpy(world_points(depth, np.stack(intrinsics), np.stack(poses)))
        item['cameras'] = torch.from_numpy(world_cameras(np.stack(poses)))
        if self.box_centres:
            item['box_centres'] = torch.from_numpy(
                box_centre_map(np.stack(instance), cameras['objects'], np.stack(poses)))
        return item


def box_centre_map(instance, objects, poses, scale=POINTS_SCALE):
    """[V,3,H,W]: per pixel, the centre of its object's world box (`bounds_min` / `bounds_max` of
    cameras.json) in the frame of `world_points`; zero on the room (instance 0) and on ids no object
    lists."""
    centre = poses[:, :3, 3].mean(axis=0)
    lookup = np.zeros((int(instance.max()) + 1, 3), np.float32)
    for o in objects:
        k = int(o['instance_id'])
        if 0 < k < len(lookup):
            box_centre = (np.asarray(o['bounds_min'], np.float64) + np.asarray(o['bounds_max'], np.float64)) / 2
            lookup[k] = (box_centre - centre) / scale
    return np.ascontiguousarray(lookup[instance].transpose(0, 3, 1, 2))


def world_cameras(poses, scale=POINTS_SCALE):
    """[V,4,4] world-from-camera poses in the frame of `world_points` (translation centred on the mean
    camera centre and divided by `scale`), the posed RGB model's camera input."""
    out = poses.astype(np.float64).copy()
    out[:, :3, 3] = (out[:, :3, 3] - out[:, :3, 3].mean(axis=0)) / scale
    return out.astype(np.float32)


def world_points(depth, intrinsics, poses, scale=POINTS_SCALE):
    """[V,3,H,W] world XYZ from depth, centred on the mean camera centre and divided by `scale`."""
    views, height, width = depth.shape
    centre = poses[:, :3, 3].mean(axis=0)
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    out = np.zeros((views, 3, height, width), np.float32)
    for i in range(views):
        k = intrinsics[i]
        z = fill_invalid_depth(depth[i]).astype(np.float64)
        valid = np.isfinite(z) & (z > 0)
        x = (u - k[0, 2]) / k[0, 0] * z
        y = (v - k[1, 2]) / k[1, 1] * z
        camera = np.stack([x, y, z], axis=0).reshape(3, -1)
        world = poses[i, :3, :3] @ camera + poses[i, :3, 3:4]
        world = world.reshape(3, height, width)
        centred = (world - centre[:, None, None]) / scale
        centred[:, ~valid] = 0.0
        out[i] = centred
    return out
