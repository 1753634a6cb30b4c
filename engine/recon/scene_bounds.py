"""Scene bounds: the box the voxel grid must cover.

Official VoRTX (vortx-spec.md section 4) takes the bounding box of every frame's image corners at
4 m depth (plus, here, the camera centres, so the cameras themselves are inside). A single outlier
pose, or a camera looking down a long corridor, would make that box huge, and the coarse grid and
fusion cost grow with its volume. So each axis longer than `max_room_size` is clipped to a window of
that length centred on the median camera centre (the median ignores a few outlier poses). World Z is
up, so the third entry of `max_room_size` is the room height allowance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.cameras import frustum_corners


@dataclass(frozen=True)
class SceneBounds:
    minimum: np.ndarray  # (3,) world metres
    maximum: np.ndarray  # (3,) world metres
    clipped: tuple[bool, bool, bool]  # which axes were cut to max_room_size

    @property
    def size(self) -> np.ndarray:
        return self.maximum - self.minimum


def scene_bounds(
    Ks: np.ndarray,
    poses: np.ndarray,
    sizes: np.ndarray,
    depth: float = 4.0,
    max_room_size: tuple[float, float, float] = (20.0, 20.0, 6.0),
) -> SceneBounds:
    """Bounds of all frusta cut at `depth`, clipped per axis to `max_room_size` (see module doc).

    Ks: (F, 3, 3); poses: (F, 4, 4) camera-to-world; sizes: (F, 2) (width, height) in pixels of K.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if len(poses) == 0:
        raise ValueError("scene bounds need at least one posed frame")
    corners = [frustum_corners(K, P, int(w), int(h), depth) for K, P, (w, h) in zip(Ks, poses, sizes)]
    points = np.concatenate([np.concatenate(corners), poses[:, :3, 3]])
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = np.median(poses[:, :3, 3], axis=0)
    limit = np.asarray(max_room_size, dtype=np.float64)
    clipped = hi - lo > limit
    lo = np.where(clipped, np.maximum(lo, centre - limit / 2), lo)
    hi = np.where(clipped, np.minimum(hi, centre + limit / 2), hi)
    return SceneBounds(lo, hi, tuple(bool(c) for c in clipped))  # type: ignore[arg-type]
