"""Sanity checks on an SfM result, turned into warnings a user can act on.

Thresholds come from the failure experiments in platform-notes section 1: a good capture of a
textured room registers (nearly) every photo in one model with a reprojection error well below
1 px and thousands of points.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..capture.naming import name_list

MIN_REGISTERED_FRACTION = 0.6
MAX_REPROJECTION_ERROR_PX = 1.5
MIN_POINTS = 100
# Corner displacement from the radial term, as a fraction of the larger image side, above which
# treating the photos as pinhole (what the reconstruction does) visibly misplaces surfaces.
MAX_DISTORTION_FRACTION = 0.005


def radial_corner_shift(K: np.ndarray, radial: Sequence[float], width: int, height: int) -> float:
    """Pixels by which the radial terms (k1, k2, ...) move the farthest image corner.

    K: (3, 3) pinhole part; radial: COLMAP's k1[, k2] of x_d = x (1 + k1 r^2 + k2 r^4).
    """
    cx, cy, f = K[0, 2], K[1, 2], 0.5 * (K[0, 0] + K[1, 1])
    corners = np.array([[0.0, 0.0], [width, 0.0], [0.0, height], [width, height]])
    r = np.max(np.linalg.norm(corners - [cx, cy], axis=1)) / f
    factor = sum(k * r ** (2 * (i + 1)) for i, k in enumerate(radial))
    return float(abs(factor) * r * f)


def quality_warnings(
    num_images: int,
    unregistered: Sequence[str],
    model_sizes: Sequence[int],
    reprojection_error_px: float,
    num_points: int,
) -> list[str]:
    """Warnings for a result whose largest model was kept."""
    warnings: list[str] = []
    registered = num_images - len(unregistered)
    if registered < MIN_REGISTERED_FRACTION * num_images:
        warnings.append(
            f"only {registered} of {num_images} photos got a camera pose; not placed: "
            f"{name_list(unregistered)}. Take photos with more overlap between neighbours."
        )
    if len(model_sizes) > 1:
        warnings.append(
            f"the photos split into {len(model_sizes)} separate groups "
            f"({', '.join(map(str, model_sizes))} photos); only the largest is used. "
            "Add photos that connect the groups."
        )
    if reprojection_error_px > MAX_REPROJECTION_ERROR_PX:
        warnings.append(
            f"mean reprojection error is {reprojection_error_px:.2f} px (above {MAX_REPROJECTION_ERROR_PX} px): "
            "poses may be inaccurate (motion blur, rolling shutter or a zooming lens?)"
        )
    if num_points < MIN_POINTS:
        warnings.append(
            f"only {num_points} 3D points were triangulated (fewer than {MIN_POINTS}): poses are weakly "
            "constrained; photograph textured surfaces"
        )
    return warnings


def significant_distortion(shift_px: float, image_size: tuple[int, int]) -> bool:
    """Whether a corner shift (pixels) matters for images of image_size (width, height)."""
    return shift_px > MAX_DISTORTION_FRACTION * max(image_size)
