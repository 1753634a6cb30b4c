"""An analytic training room for the training, evaluation and DDP tests (no Blender, no files)."""

from __future__ import annotations

import math

import numpy as np

from engine.geometry.cameras import look_along
from engine.train.crops import crop_points
from engine.train.rooms import RoomData


def box_room(
    size=(3.0, 2.6, 2.4), n_frames: int = 12, image_size=(64, 48), voxel: float = 0.04, seed: int = 0,
    trunc: float = 0.12,
) -> RoomData:
    """An analytic box room (no Blender): textured RGB, exact depth, exact TSDF.

    The room spans [0, size] with walls at its faces; cameras at 1.2 m height on a circle look
    outward at the walls."""
    rng = np.random.default_rng(seed)
    W, H = image_size
    f = 0.8 * W
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    center = np.array(size) / 2
    poses, images, depths = [], [], []
    lo, hi = np.zeros(3), np.array(size)
    uu, vv = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)  # pixel centres (pixel j covers [j, j+1))
    rays_cam = np.stack([(uu - K[0, 2]) / f, (vv - K[1, 2]) / f, np.ones_like(uu, dtype=float)], -1)
    for i in range(n_frames):
        a = 2 * math.pi * i / n_frames
        t = center + 0.3 * np.array([math.cos(a), math.sin(a), 0]) + np.array([0, 0, 1.2 - center[2]])
        pose = look_along(t, [math.cos(a), math.sin(a), -0.15])
        R = pose[:3, :3]
        dirs = rays_cam @ R.T  # world directions, z_cam = 1
        with np.errstate(divide="ignore", invalid="ignore"):
            tl = np.where(dirs > 0, (hi - t) / dirs, (lo - t) / dirs)
        tl = np.where(np.isfinite(tl) & (tl > 0), tl, np.inf)
        depth = tl.min(-1)  # planar depth since rays have z_cam = 1
        hit = t + dirs * depth[..., None]
        checker = (np.floor(hit * 4).sum(-1) % 2).astype(np.float32)
        rgb = np.stack([120 + 80 * checker, 100 + 60 * np.sin(hit[..., 0] * 3), 90 + 50 * np.cos(hit[..., 1] * 5)], -1)
        rgb = rgb + rng.normal(0, 3, rgb.shape)
        poses.append(pose)
        images.append(np.clip(rgb, 0, 255).astype(np.uint8))
        depths.append(depth.astype(np.float32))
    # exact TSDF: -min(1, d/trunc) inside (free, observed), behind the walls up to trunc: +d/trunc, else +1
    origin = -np.array([0.2, 0.2, 0.2])
    dims = np.ceil((np.array(size) + 0.4) / voxel).astype(int) + 1
    p = crop_points(origin, dims, voxel).reshape(*dims, 3)
    inside = np.all((p > lo) & (p < hi), -1)
    d_in = np.minimum(p - lo, hi - p).min(-1)
    d_out = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0), axis=-1)
    tsdf = np.where(inside, -np.minimum(1, d_in / trunc), np.where(d_out < trunc, d_out / trunc, 1.0))
    return RoomData(
        name=f"box{seed}", images=np.stack(images), depths=np.stack(depths), K=np.repeat(K[None], n_frames, 0),
        poses=np.stack(poses), tsdf=tsdf.astype(np.float32), tsdf_origin=origin, voxel_size=voxel,
    )
