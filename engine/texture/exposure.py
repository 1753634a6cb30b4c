"""Evening out exposure and white balance between photos: one RGB gain per photo.

Phones re-expose as they turn from a window to a dark corner, so the same wall is brighter in one
photo than in the next; blended unchanged, chart borders and view changes would show as steps. Each
photo's gain maps its colours onto the consensus of all photos that see the same surface points
(in linear light, where exposure is a factor). Solved by alternating: consensus = weighted mean of
the gained samples; gain = median over the photo's points of consensus / sample (robust to
occlusion mistakes and specular highlights); gains normalised to a geometric mean of 1, so the
texture keeps the capture's overall brightness.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_SAMPLE = 0.02  # linear values below this are mostly noise: not used to estimate a gain
GAIN_LIMITS = (1 / 3, 3.0)
ITERATIONS = 5


@dataclass
class ViewSamples:
    """One photo's samples: ids (M,) of the surface points it sees, colours (M, 3) linear, weights (M,)."""

    ids: np.ndarray
    colours: np.ndarray
    weights: np.ndarray


def exposure_gains(samples: list[ViewSamples], point_count: int) -> np.ndarray:
    """(n_views, 3) float32 per-channel gains; 1 for photos that share no point with another photo."""
    n = len(samples)
    gains = np.ones((n, 3), np.float64)
    seen_by = np.zeros(point_count, np.int64)
    for s in samples:
        seen_by[s.ids] += 1
    shared = seen_by >= 2
    for _ in range(ITERATIONS):
        total = np.zeros((point_count, 3))
        weight = np.zeros(point_count)
        for g, s in zip(gains, samples):
            total[s.ids] += s.weights[:, None] * s.colours * g
            weight[s.ids] += s.weights
        consensus = total / np.maximum(weight, 1e-12)[:, None]
        for i, s in enumerate(samples):
            use = shared[s.ids] & (s.colours > MIN_SAMPLE).all(axis=1)
            if use.sum() < 10:
                continue
            ratio = consensus[s.ids[use]] / s.colours[use]
            gains[i] = np.exp(np.median(np.log(np.maximum(ratio, 1e-6)), axis=0))
        gains = np.clip(gains, *GAIN_LIMITS)
        gains /= np.exp(np.log(gains).mean(axis=0, keepdims=True))
    return gains.astype(np.float32)
