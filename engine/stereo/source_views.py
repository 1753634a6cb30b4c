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
