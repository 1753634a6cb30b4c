"""Keyframes and view selection: the one rule that training crops and inference tiles share.

A model should see at inference the kind of views it was trained with, so both paths call these
functions (engine/train/crops.py for a training crop, engine/recon/tiles.py for an inference tile):

1. Keyframes (`select_keyframes`, NeuralRecon rule, vortx-spec.md section 2): walk the frames in
   capture order and keep one when, against the last *kept* frame, the camera moved more than
   0.1 m or its optical axis turned more than 15 degrees. The first finite pose is always kept.
2. Views of a block of voxels (`select_views`): up to n keyframes, uniformly without replacement,
   among the keyframes that see at least one of the block's points (projects to 0 <= u < W,
   0 <= v < H with z > 0). Unlike the official code, a block with no more than n such keyframes takes
   only those (the official code then takes *all* keyframes; views that see none of the block only
   add masked-out tokens and cost).
3. Training stacks a fixed number of views per crop, so `top_up_views` fills a short selection with
   random other frames (spec: "if too few qualify, other frames are added").

The points are what each path has: every 100th fine voxel of a training crop, the coarse voxels of
an inference tile.
"""

from __future__ import annotations

import numpy as np

from .cameras import project_points, world_to_camera


# The keyframe rule's defaults (vortx-spec.md section 2): the reconstruction's settings and the pose
# refinement (which adjusts the frames reconstruction will use) read them from here.
DEFAULT_KEYFRAME_TRANSLATION_M = 0.1
DEFAULT_KEYFRAME_ANGLE_DEG = 15.0


def select_keyframes(poses: np.ndarray, min_translation: float = DEFAULT_KEYFRAME_TRANSLATION_M,
                     min_angle_deg: float = DEFAULT_KEYFRAME_ANGLE_DEG) -> np.ndarray:
    """Indices (K,) int64 of the kept frames, in input order; frames with non-finite poses are skipped.

    poses: (F, 4, 4) camera-to-world, OpenCV axes (the optical axis is the rotation's third column).
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"poses must be (F, 4, 4), got {poses.shape}")
    cos_limit = np.cos(np.deg2rad(min_angle_deg))
    kept: list[int] = []
    for i, pose in enumerate(poses):
        if not np.all(np.isfinite(pose)):
            continue
        if not kept:
            kept.append(i)
            continue
        last = poses[kept[-1]]
        moved = np.linalg.norm(pose[:3, 3] - last[:3, 3]) > min_translation
        axis, last_axis = pose[:3, 2], last[:3, 2]
        # Comparing cosines avoids arccos's loss of precision near 0 deg.
        turned = float(np.dot(axis, last_axis) / (np.linalg.norm(axis) * np.linalg.norm(last_axis))) < cos_limit
        if moved or turned:
            kept.append(i)
    return np.asarray(kept, dtype=np.int64)


def views_seeing_points(points: np.ndarray, Ks: np.ndarray, poses: np.ndarray, sizes: np.ndarray, chunk: int = 64) -> np.ndarray:
    """(V,) bool: does view v see at least one of `points`?

    points: (M, 3) world; Ks: (V, 3, 3) pixels; poses: (V, 4, 4) camera-to-world; sizes: (V, 2)
    (width, height) in pixels of K. "Sees" = projects to 0 <= u < W, 0 <= v < H with z > 0 (pixel j
    covers [j, j + 1)). Views are processed `chunk` at a time to bound the (chunk, M) buffers.

    A view's visible region is convex (five half-spaces), so the points' bounding box decides most
    views from its 8 corners: all inside, the view sees every point; all outside one half-space, it
    sees none. Only views whose border cuts the box project the points (a tile of a big space is
    seen whole or not at all by most of its keyframes).
    """
    points = np.asarray(points, dtype=np.float64)
    sizes = np.asarray(sizes)
    seen = np.zeros(len(poses), dtype=bool)
    if len(points) == 0 or len(poses) == 0:
        return seen
    inside_all, outside_one = _box_in_views(points.min(axis=0), points.max(axis=0), Ks, poses, sizes)
    seen[inside_all] = True
    open_views = np.flatnonzero(~inside_all & ~outside_one)
    for a in range(0, len(open_views), chunk):
        views = open_views[a:a + chunk]
        u, v, z = project_points(points, Ks[views], poses[views])
        w, h = sizes[views, 0, None], sizes[views, 1, None]
        inside = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        seen[views] = inside.any(axis=1)
    return seen


# Corners this close to a view's border (relative to their depth) leave the view to the exact test.
_BORDER_MARGIN = 1e-6


def _box_in_views(lo: np.ndarray, hi: np.ndarray, Ks: np.ndarray, poses: np.ndarray, sizes: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """For the box [lo, hi] (3,) world: (V,) bool "all 8 corners inside view v's visible region" and
    (V,) bool "all 8 corners outside one of its half-spaces" (z > 0, K_u . c >= 0, W z - K_u . c > 0,
    K_v . c >= 0, H z - K_v . c > 0 for camera point c), each with a margin: a corner near a border
    decides neither."""
    bits = (np.arange(8)[:, None] >> np.arange(3)) & 1
    corners = np.where(bits, hi, lo)  # (8, 3)
    cam = world_to_camera(corners, np.asarray(poses, np.float64))  # (V, 8, 3)
    Ks = np.asarray(Ks, np.float64)
    z = cam[..., 2]
    ku = np.einsum("vj,vmj->vm", Ks[:, 0], cam)  # z * u
    kv = np.einsum("vj,vmj->vm", Ks[:, 1], cam)  # z * v
    w, h = np.asarray(sizes, np.float64)[:, 0, None], np.asarray(sizes, np.float64)[:, 1, None]
    scale = np.abs(z) * np.maximum(w, h) + np.linalg.norm(cam, axis=-1)
    margin = _BORDER_MARGIN * scale
    spaces = np.stack([z, ku, w * z - ku, kv, h * z - kv])  # (5, V, 8): > 0 inside
    inside_all = np.all(spaces > margin, axis=(0, 2))
    outside_one = np.any(np.all(spaces < -margin, axis=2), axis=0)
    return inside_all, outside_one


def sample_views(candidates: np.ndarray, max_views: int, rng: np.random.Generator) -> np.ndarray:
    """Up to `max_views` of `candidates` (1-D int array), uniformly without replacement, sorted.

    The draw is made even when all candidates are taken (it then only permutes them, and sorting
    undoes that), so the generator advances the same way whatever the count: a training crop's later
    random choices do not depend on how many keyframes saw it."""
    candidates = np.asarray(candidates, dtype=np.int64)
    if len(candidates) == 0:
        return candidates
    return np.sort(rng.choice(candidates, size=min(max_views, len(candidates)), replace=False))


def select_views(
    points: np.ndarray,
    Ks: np.ndarray,
    poses: np.ndarray,
    sizes: np.ndarray,
    keyframes: np.ndarray,
    max_views: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Frame indices (<= max_views,) int64, sorted: keyframes that see at least one of `points`,
    sampled as in `sample_views`; empty when none does.

    Ks (F, 3, 3), poses (F, 4, 4), sizes (F, 2) (width, height) for all F frames; keyframes (K,)
    indices into them; points (M, 3) world.
    """
    keyframes = np.asarray(keyframes, dtype=np.int64)
    seen = views_seeing_points(points, Ks[keyframes], poses[keyframes], np.asarray(sizes)[keyframes])
    return sample_views(keyframes[seen], max_views, rng)


def top_up_views(chosen: np.ndarray, n_frames: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """Exactly `count` frame indices, sorted: `chosen` plus random other frames (uniform, without
    replacement) and, when there are fewer than `count` frames in all, random repeats."""
    chosen = [int(i) for i in chosen]
    if len(chosen) < count:
        rest = np.setdiff1d(np.arange(n_frames), np.asarray(chosen, dtype=np.int64))
        chosen += [int(i) for i in rng.choice(rest, size=min(count - len(chosen), len(rest)), replace=False)]
    if len(chosen) < count:
        chosen += [int(i) for i in rng.choice(np.asarray(chosen), size=count - len(chosen), replace=True)]
    return np.sort(np.asarray(chosen, dtype=np.int64))
