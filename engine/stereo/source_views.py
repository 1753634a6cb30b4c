"""Which photos a reference view is matched against.

The DeepVideoMVS / SimpleRecon rule (stereo-evidence.md): rank candidates by the penalty
`R^2 + (t - t_ideal)^2`, multiplied by 5 when the baseline t is shorter than t_ideal, where
R = sqrt(2 (1 - tr(R_rel) / 3)) measures the relative rotation. A short baseline triangulates badly,
a large rotation shrinks the overlap; views that look more than `max_angle_deg` away, or sit on the
reference's own position, are never used.
"""

from __future__ import annotations

import numpy as np

IDEAL_BASELINE = 0.15  # metres (SimpleRecon's value for hand-held indoor video)
MIN_BASELINE = 0.02  # metres: closer than this the views are duplicates, not stereo
MAX_ANGLE_DEG = 60.0  # optical axes further apart than this see too little in common
# Triangulation rule (OpenMVS's view score; COLMAP's minimum angle): the angle a point subtends between
# the two cameras should be near IDEAL_TRIANGULATION_DEG; below MIN_TRIANGULATION_DEG depth is too
# uncertain, and the source must see a good share of what the reference sees.
IDEAL_TRIANGULATION_DEG = 12.0
MIN_TRIANGULATION_DEG = 3.0
TRIANGULATION_SIGMA_DEG = 8.0  # falloff of the score away from the ideal angle
MIN_SHARED = 0.2  # share of the reference's points the source must see
SCENE_SAMPLES = 12  # per image side: the reference pixels lifted to its median depth when no sparse points are given


def pose_penalties(poses: np.ndarray, reference: int, ideal_baseline: float = IDEAL_BASELINE) -> np.ndarray:
    """(F,) penalty of every view as a source for `reference` (inf for unusable ones, incl. itself).

    poses: (F, 4, 4) camera-to-world, OpenCV axes.
    """
    poses = np.asarray(poses, dtype=np.float64)
    ref = poses[reference]
    baseline = np.linalg.norm(poses[:, :3, 3] - ref[:3, 3], axis=1)
    relative = np.einsum("ji,fjk->fik", ref[:3, :3], poses[:, :3, :3])  # R_ref^T R_f
    trace = np.trace(relative, axis1=1, axis2=2)
    rotation = np.sqrt(np.clip(2.0 * (1.0 - trace / 3.0), 0.0, None))
    penalty = rotation ** 2 + (baseline - ideal_baseline) ** 2
    penalty = np.where(baseline < ideal_baseline, 5.0 * penalty, penalty)
    axes = poses[:, :3, 2]
    cos_angle = axes @ ref[:3, 2]
    unusable = (baseline < MIN_BASELINE) | (cos_angle < np.cos(np.deg2rad(MAX_ANGLE_DEG)))
    penalty[unusable] = np.inf
    penalty[reference] = np.inf
    return penalty


def select_sources(poses: np.ndarray, reference: int, count: int) -> np.ndarray:
    """Up to `count` source positions (int64, best first) for the view at `reference`."""
    penalty = pose_penalties(poses, reference)
    order = np.argsort(penalty, kind="stable")
    return order[np.isfinite(penalty[order])][:count].astype(np.int64)


def scene_points(K: np.ndarray, pose: np.ndarray, size: tuple[int, int], depth: float,
                 depth_map: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) world points where a SCENE_SAMPLES x SCENE_SAMPLES grid of the reference's pixels meets
    the plane at `depth`: what the reference sees when no sparse points tell it. With `depth_map`
    (h, w) at `size` (0 = none, e.g. the sparse points' seed), a pixel it covers is lifted to its depth."""
    w, h = size
    u, v = np.meshgrid((np.arange(SCENE_SAMPLES) + 0.5) * w / SCENE_SAMPLES,
                       (np.arange(SCENE_SAMPLES) + 0.5) * h / SCENE_SAMPLES)
    u, v = u.ravel(), v.ravel()
    depths = np.full(u.size, float(depth))
    if depth_map is not None:
        known = depth_map[np.minimum(v.astype(int), h - 1), np.minimum(u.astype(int), w - 1)]
        depths = np.where(known > 0, known, depths)
    rays = np.linalg.inv(K) @ np.stack([u, v, np.ones(u.size)])
    return (pose[:3, :3] @ (rays * depths) + pose[:3, 3:4]).T


def triangulation_scores(poses: np.ndarray, Ks: np.ndarray, sizes: np.ndarray, reference: int,
                         points: np.ndarray) -> np.ndarray:
    """(F,) score of every view as a source for `reference`: the sum over the reference's `points`
    (n, 3, world) that the view also sees of a Gaussian in the triangulation angle around the ideal,
    0 below the minimum angle; 0 for the reference itself and views sharing under MIN_SHARED.

    poses (F, 4, 4) camera-to-world; Ks (F, 3, 3); sizes (F, 2) (w, h) of the images the Ks are for.
    """
    poses = np.asarray(poses, dtype=np.float64)
    centres = poses[:, :3, 3]
    scores = np.zeros(len(poses))
    if len(points) == 0:
        return scores
    to_ref = points - centres[reference]
    for f in range(len(poses)):
        if f == reference:
            continue
        cam = (points - centres[f]) @ poses[f, :3, :3]
        z = cam[:, 2]
        front = z > 1e-6
        zs = np.where(front, z, 1.0)
        u = Ks[f, 0, 0] * cam[:, 0] / zs + Ks[f, 0, 2]
        v = Ks[f, 1, 1] * cam[:, 1] / zs + Ks[f, 1, 2]
        seen = front & (u >= 0) & (u < sizes[f, 0]) & (v >= 0) & (v < sizes[f, 1])
        if seen.mean() < MIN_SHARED:
            continue
        to_src = points[seen] - centres[f]
        a = to_ref[seen]
        cos = np.sum(a * to_src, axis=1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(to_src, axis=1), 1e-12)
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        score = np.exp(-(angle - IDEAL_TRIANGULATION_DEG) ** 2 / (2 * TRIANGULATION_SIGMA_DEG ** 2))
        scores[f] = float(np.sum(np.where(angle >= MIN_TRIANGULATION_DEG, score, 0.0))) / len(points)
    return scores


def select_sources_by_triangulation(poses: np.ndarray, Ks: np.ndarray, sizes: np.ndarray, reference: int, count: int,
                                    points: np.ndarray) -> np.ndarray:
    """Up to `count` source positions (int64, best first) for `reference` by `triangulation_scores`."""
    scores = triangulation_scores(poses, Ks, sizes, reference, points)
    order = np.argsort(-scores, kind="stable")
    return order[scores[order] > 0][:count].astype(np.int64)
