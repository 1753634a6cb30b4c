"""A textured box room ray-cast into photos with plain numpy (no engine code): what SfM registers
reliably, for the Blender Estimate Poses test and the installed-extension test."""

from __future__ import annotations

import cv2
import numpy as np

TEXEL = 0.01  # metres per texture pixel on the walls


def wall_textures(seed: int) -> np.ndarray:
    """(6, 512, 512, 3) uint8: many small shapes plus grain, so SIFT finds corners at several scales."""
    rng = np.random.default_rng(seed)
    walls = []
    for _ in range(6):
        tex = np.full((512, 512, 3), 128, np.uint8)
        for _ in range(4000):
            centre = tuple(int(v) for v in rng.integers(0, 512, 2))
            colour = tuple(int(v) for v in rng.integers(0, 256, 3))
            if rng.random() < 0.5:
                cv2.circle(tex, centre, int(rng.integers(2, 9)), colour, -1, cv2.LINE_AA)
            else:
                w, h = (int(v) for v in rng.integers(3, 12, 2))
                cv2.rectangle(tex, centre, (centre[0] + w, centre[1] + h), colour, -1)
        walls.append(np.clip(tex.astype(np.int16) + rng.integers(-20, 21, tex.shape), 0, 255).astype(np.uint8))
    return np.stack(walls)


def render_room(K: np.ndarray, pose: np.ndarray, size: tuple[int, int], room: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """Ray-cast the inside of the box [0, room] (pixel centres at +0.5, OpenCV camera axes)."""
    w, h = size
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = (np.stack([cols, rows, np.ones_like(cols)], -1) @ np.linalg.inv(K).T) @ pose[:3, :3].T
    centre = pose[:3, 3]
    safe = np.where(np.abs(rays) > 1e-12, rays, 1e-12)
    t_axis = np.where(rays > 0, (room - centre) / safe, -centre / safe)
    axis = np.argmin(t_axis, -1)
    hit = centre + np.take_along_axis(t_axis, axis[..., None], -1) * rays
    face = axis * 2 + (np.take_along_axis(rays, axis[..., None], -1)[..., 0] > 0)
    uv = np.take_along_axis(hit, np.stack([(axis + 1) % 3, (axis + 2) % 3], -1), -1)
    texel = np.floor(uv / TEXEL).astype(np.int64) % walls.shape[1]
    return walls[face, texel[..., 0], texel[..., 1]]
