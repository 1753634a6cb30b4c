"""Cleaning one stereo depth map before fusion, and how much each of its depths should count there.

- Speckles: small connected regions of depth (neighbours within a relative step) are matching noise,
  not surfaces (OpenMVS and COLMAP drop them the same way).
- Median: a 5 x 5 median over the pixels that have depth takes the per-pixel jitter of a plane sweep
  out of flat surfaces; it never fills a hole and never moves a depth across an edge (a pixel keeps
  its own depth where the median disagrees with it by more than the edge tolerance).
- Observation weight (KinectFusion-style): confidence x cosine of the viewing angle x the inverse
  square of the expected depth error, which for stereo grows with depth squared over the baseline.
"""

from __future__ import annotations

import warnings
from typing import Optional

import cv2
import numpy as np

from ..geometry.depth_normals import depth_normals

SPECKLE_STEP = 0.05  # neighbouring depths within 5 % belong to the same region (2 % split noisy real surfaces apart)
SPECKLE_SHARE = 0.002  # regions under 0.2 % of the image (60 pixels at 200 x 150) are speckles
MEDIAN_SIZE = 5
EDGE_TOLERANCE = 0.05  # a median more than 5 % away from the pixel's depth is across an edge: keep the depth
MIN_COSINE = 0.2  # grazing views still count a little (floors are often seen at 70-80 degrees)
REFERENCE_ERROR_DEPTH = 1.0  # metres: the depth whose observation weighs 1 (before confidence and angle)


def remove_speckles(depth: np.ndarray, share: float = SPECKLE_SHARE, step: float = SPECKLE_STEP) -> np.ndarray:
    """(H, W) bool: the pixels of `depth` that lie in small connected regions (to be dropped)."""
    valid = depth > 0
    if not valid.any():
        return np.zeros_like(valid)
    # Log depth in units of `step` as int16 for OpenCV's region growing; 0 is "no depth".
    code = np.zeros(depth.shape, np.int16)
    code[valid] = np.clip(np.round((np.log(depth[valid]) + 5.0) / step), 1, 32000).astype(np.int16)
    filtered = code.copy()
    cv2.filterSpeckles(filtered, 0, max(1, int(share * depth.size)), 1)
    return valid & (filtered == 0)


def median_depth(depth: np.ndarray, size: int = MEDIAN_SIZE, tolerance: float = EDGE_TOLERANCE) -> np.ndarray:
    """(H, W) float32: each depth replaced by the median of the depths in its window (holes stay holes)."""
    h, w = depth.shape
    half = size // 2
    padded = np.pad(np.where(depth > 0, depth, np.nan).astype(np.float32), half, constant_values=np.nan)
    stack = np.stack([padded[dy:dy + h, dx:dx + w] for dy in range(size) for dx in range(size)])
    with np.errstate(all="ignore"):

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            median = np.nanmedian(stack, axis=0)
    keep_own = ~np.isfinite(median) | (np.abs(median - depth) > tolerance * np.maximum(depth, 1e-6))
    return np.where(depth > 0, np.where(keep_own, depth, median), 0.0).astype(np.float32)


def observation_weights(depth: np.ndarray, confidence: np.ndarray, K: np.ndarray,
                        normals: Optional[np.ndarray] = None) -> np.ndarray:
    """(H, W) float32 weight of each depth in fusion: confidence x max(cos(view angle), MIN_COSINE) /
    (depth / REFERENCE_ERROR_DEPTH)^2; 0 where there is no depth. The viewing angle comes from
    `normals` (H, W, 3) when the matcher estimated them (PatchMatch's planes), else from the depth map's
    own differences (noisy on a sweep's stepped depths)."""
    h, w = depth.shape
    if normals is not None:
        ok = np.linalg.norm(normals, axis=-1) > 0.5
    else:
        normals, ok = depth_normals(depth, K)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(u + 0.5 - K[0, 2]) / K[0, 0], (v + 0.5 - K[1, 2]) / K[1, 1], np.ones((h, w))], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    cosine = np.where(ok, np.abs(np.sum(normals * rays, axis=-1)), 0.5)
    z = np.maximum(depth.astype(np.float64), 1e-3) / REFERENCE_ERROR_DEPTH
    weight = np.clip(confidence, 0, 1) * np.maximum(cosine, MIN_COSINE) / z ** 2
    return np.where(depth > 0, weight, 0.0).astype(np.float32)
