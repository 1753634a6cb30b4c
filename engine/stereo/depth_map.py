"""One reference view's stereo depth map: the record the matchers write and the filters, the fusion and
the finishing read (its own module, so that depth_maps.py and view_agreement.py can both use it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np


@dataclass
class DepthMap:
    """One reference view's stereo result, at the stereo resolution."""

    frame: int  # position in the frame list given to `estimate_depth_maps`
    depth: np.ndarray  # (h, w) float32 metres (planar z), 0 = no depth
    confidence: np.ndarray  # (h, w) float32 in [0, 1], 0 where no depth
    K: np.ndarray  # (3, 3) float64 in pixels of `depth`
    pose: np.ndarray  # (4, 4) float64 camera-to-world
    sources: np.ndarray  # (S,) int64 positions of the source frames used
    depth_range: tuple[float, float]  # (near, far) metres swept
    normal: Optional[np.ndarray] = None  # (h, w, 3) float32 unit camera-frame normals (PatchMatch's planes), None for the sweep
    # (metres, share of the depth) a point may lie off this map's depth and be the surface it saw
    # (engine/finish/free_space.py's votes); None: stereo's accuracy
    agreement: Optional[tuple[float, float]] = None

    @property
    def completeness(self) -> float:
        """Share of pixels with a depth."""
        return float((self.depth > 0).mean())
