"""Scene bounds: the box the voxel grid must cover.

Official VoRTX (vortx-spec.md section 4) takes the bounding box of every frame's image corners at
4 m depth (plus, here, the camera centres, so the cameras themselves are inside). That box is where
the cameras *could* see, not where the room is: a camera tilted down a little has a frustum that
reaches metres below the floor, so the frusta of an ordinary 3 m high room span more than 6 m in z.
The extent of the room comes from evidence, the sparse points (SfM's, a COLMAP model's, the pose
refinement's, a phone's depth) that lie on its surfaces:
- an axis along which the frusta stay within `max_room_size` keeps the frusta's extent (as official);
- a longer axis is cut to where the sparse points are (their 0.5-99.5 percentile box, grown by
  EVIDENCE_MARGIN_M, together with the camera centres), however long that is: a 32 m corridor is
  reconstructed whole, in blocks whose memory does not grow with it (engine/recon/block_fusion.py);
- only when there are no sparse points to say is such an axis clipped to a window of `max_room_size`
  centred on the median camera centre (the median ignores a few outlier poses), so frusta alone
  cannot make the voxel grid city-sized. `evidence_exceeds` are the axes where the evidence is larger
  than the maximum room size (reported, not cut).
World Z is up, so the third entry of `max_room_size` is the room height allowance. The stereo method
adds its own evidence afterwards, its depth maps (`engine/recon/stereo_fusion.py`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..geometry.cameras import frustum_corners

MIN_EVIDENCE_POINTS = 20  # fewer sparse points than this say nothing about the room's extent
EVIDENCE_PERCENTILE = 0.5  # per side and axis: a few wild points (mismatches) do not stretch the box
EVIDENCE_MARGIN_M = 0.5  # the points lie on surfaces; the margin keeps the surfaces' far sides and sparse corners
FRUSTA = "camera frusta"
SPARSE_POINTS = "sparse points"


@dataclass(frozen=True)
class SceneBounds:
    minimum: np.ndarray  # (3,) world metres
    maximum: np.ndarray  # (3,) world metres
    clipped: tuple[bool, bool, bool]  # which axes were cut to max_room_size around the median camera (no evidence)
    # What the extent rests on: FRUSTA (no sparse points), or SPARSE_POINTS (the frusta cut to them).
    source: str = FRUSTA
    # The axes along which the evidence (sparse points) itself spans more than max_room_size (kept whole).
    evidence_exceeds: tuple[bool, bool, bool] = (False, False, False)

    @property
    def size(self) -> np.ndarray:
        return self.maximum - self.minimum

    def to_dict(self) -> dict:
        """The sidecar's "bounds" entry."""
        return {"min": self.minimum.tolist(), "max": self.maximum.tolist(), "clipped": list(self.clipped),
                "source": self.source, "evidence_exceeds": list(self.evidence_exceeds)}


def evidence_box(points: np.ndarray, percentile: float = EVIDENCE_PERCENTILE) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of points (N, 3), the `percentile` lowest and highest per axis left out."""
    points = np.asarray(points, dtype=np.float64)
    return np.percentile(points, percentile, axis=0), np.percentile(points, 100 - percentile, axis=0)


def scene_bounds(
    Ks: np.ndarray,
    poses: np.ndarray,
    sizes: np.ndarray,
    depth: float = 4.0,
    max_room_size: tuple[float, float, float] = (20.0, 20.0, 6.0),
    points: Optional[np.ndarray] = None,
) -> SceneBounds:
    """Bounds of all frusta cut at `depth`, cut to the sparse `points` (N, 3) where the frusta are
    longer than `max_room_size`; without points, clipped per axis to `max_room_size` (see module doc).

    Ks: (F, 3, 3); poses: (F, 4, 4) camera-to-world; sizes: (F, 2) (width, height) in pixels of K.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if len(poses) == 0:
        raise ValueError("scene bounds need at least one posed frame")
    centres = poses[:, :3, 3]
    corners = [frustum_corners(K, P, int(w), int(h), depth) for K, P, (w, h) in zip(Ks, poses, sizes)]
    frusta = np.concatenate([np.concatenate(corners), centres])
    lo, hi = frusta.min(axis=0), frusta.max(axis=0)
    limit = np.asarray(max_room_size, dtype=np.float64)
    too_long = hi - lo > limit
    source, exceeds = FRUSTA, np.zeros(3, dtype=bool)
    if points is not None:
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        points = points[np.isfinite(points).all(axis=1)]
    if points is not None and len(points) >= MIN_EVIDENCE_POINTS:
        source = SPARSE_POINTS
        seen_lo, seen_hi = evidence_box(points)
        seen_lo = np.minimum(seen_lo, centres.min(axis=0)) - EVIDENCE_MARGIN_M
        seen_hi = np.maximum(seen_hi, centres.max(axis=0)) + EVIDENCE_MARGIN_M
        cut_lo, cut_hi = np.maximum(lo, seen_lo), np.minimum(hi, seen_hi)
        cut = too_long & (cut_hi > cut_lo)  # points outside every frustum say nothing about what is seen
        lo, hi = np.where(cut, cut_lo, lo), np.where(cut, cut_hi, hi)
        exceeds = hi - lo > limit
        clipped = np.zeros(3, dtype=bool)
    else:
        clipped = too_long
    centre = np.median(centres, axis=0)
    lo = np.where(clipped, np.maximum(lo, centre - limit / 2), lo)
    hi = np.where(clipped, np.minimum(hi, centre + limit / 2), hi)
    return SceneBounds(lo, hi, tuple(bool(c) for c in clipped), source,  # type: ignore[arg-type]
                       tuple(bool(e) for e in exceeds))  # type: ignore[arg-type]
