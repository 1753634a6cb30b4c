"""Keyframe selection: drop near-duplicate frames before the expensive 2D CNN.

The NeuralRecon rule that VoRTX uses (vortx-spec.md section 2): walk the frames in capture order and
keep one when, against the last *kept* frame, the camera moved more than `min_translation` metres
or its optical axis turned more than `min_angle_deg` degrees. The first frame is always kept.
"""

from __future__ import annotations

import numpy as np


def select_keyframes(poses: np.ndarray, min_translation: float = 0.1, min_angle_deg: float = 15.0) -> list[int]:
    """Indices of the kept frames, in input order.

    poses: (F, 4, 4) camera-to-world, OpenCV axes (the optical axis is the rotation's third column).
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"poses must be (F, 4, 4), got {poses.shape}")
    if len(poses) == 0:
        return []
    centres = poses[:, :3, 3]
    axes = poses[:, :3, 2] / np.linalg.norm(poses[:, :3, 2], axis=1, keepdims=True)
    cos_limit = np.cos(np.deg2rad(min_angle_deg))
    kept = [0]
    for i in range(1, len(poses)):
        last = kept[-1]
        moved = np.linalg.norm(centres[i] - centres[last]) > min_translation
        # Comparing cosines avoids arccos's loss of precision near 0 deg.
        turned = float(np.dot(axes[i], axes[last])) < cos_limit
        if moved or turned:
            kept.append(i)
    return kept
