"""Gravity from the photos' vertical lines: door frames, wall corners, cabinet edges, window bars.

The cameras' mean up (`engine.geometry.cameras.mean_up_direction`) is biased by however the phone
was held: a corridor walked with the phone tilted down puts it 14 degrees off. Vertical lines in a
room are vertical whatever the camera does, so they measure gravity directly. With the camera
rotations known (SfM), each image segment defines its interpretation plane, the plane through the
camera centre and the segment; its normal n (world axes) is perpendicular to the 3D line. For every
vertical line n . up = 0, so up is the direction most perpendicular to the normals of the segments
that are vertical:

1. segments from OpenCV's line segment detector on each photo (as the engine sees it: EXIF
   orientation applied, undistorted when SfM undistorted the photos), downscaled to
   `MAX_SIDE` px; short segments are dropped (`MIN_LENGTH_FRACTION` of the image diagonal, at least
   `MIN_LENGTH_PX`);
2. candidates: segments whose plane contains a direction within `MAX_OFF_PRIOR_DEG` of the prior up
   (the cameras' mean up), i.e. |n . prior| < sin(MAX_OFF_PRIOR_DEG);
3. RANSAC over pairs of candidates (up = n1 x n2), inliers within `INLIER_DEG`; the winner is
   refitted as the eigenvector of the smallest eigenvalue of sum(length * n n^T) over its inliers.

Accepted only with `MIN_LINES` inlier segments in `MIN_PHOTOS` photos; otherwise None and the caller
keeps its prior. Horizontal lines whose plane happens to contain the vertical (a floor seam running
straight away below the camera) satisfy the same equation, so they do not bias the answer.

It lives in engine/capture, below engine/poses, because both levels use it: the Record3D loader
levels its world with it as it reads the export (`record3d.py`), and the SfM alignment
(`engine/poses/gravity.py`) and the bend search (`engine/poses/bends.py`) build on it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from .images import load_image
from .model import Frame
from ..errors import CaptureError
from ..geometry.cameras import scale_intrinsics

MAX_SIDE = 640  # photos are read at this larger side: segments a few pixels long still fit in
MAX_PHOTOS = 80  # an evenly spaced subset of the posed photos; more adds time, not accuracy
MIN_LENGTH_FRACTION = 0.04  # a segment shorter than this share of the image diagonal is noise
MIN_LENGTH_PX = 16.0  # ... and one this short pins no direction down in any photo (a thumbnail gives none)
MAX_OFF_PRIOR_DEG = 25.0  # how far the cameras' mean up may be from gravity for a hand-held capture
INLIER_DEG = 0.75  # |angle between a segment's plane and up| for an inlier
RANSAC_ITERATIONS = 500
MIN_LINES = 30
MIN_PHOTOS = 3
# One photo's own up (`photo_up`): at least this many segments within PHOTO_INLIER_DEG of it (of its
# PHOTO_MAX_LINES longest near the capture's up), spread over directions (the second eigenvalue of
# their planes at least PHOTO_MIN_SPREAD of the total).
PHOTO_MIN_LINES = 6
PHOTO_MAX_LINES = 60
PHOTO_INLIER_DEG = 1.5
PHOTO_MIN_SPREAD = 0.02


@dataclass(frozen=True)
class LineGravity:
    """Up (world axes, unit (3,)) as the vertical lines in the photos measure it."""

    up: np.ndarray
    lines: int  # inlier segments
    photos: int  # photos with at least one inlier segment
    candidates: int  # segments near the prior's vertical
    spread_deg: float  # RMS angle of the inlier planes from `up`
    off_prior_deg: float  # angle between `up` and the prior

    def describe(self) -> str:
        return (f"up from {self.lines} vertical lines in {self.photos} photos ({self.off_prior_deg:.1f} deg from the "
                f"cameras' mean up)")


def segment_plane_normals(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """The line segments of `frame`'s photo as interpretation-plane normals in world axes.

    Returns (normals (M, 3) unit, lengths (M,) in pixels of the downscaled photo).
    """
    import cv2  # defers cv2 (OpenCV) off the light paths

    assert frame.pose is not None and frame.K is not None
    rgb = load_image(frame.image_path)
    h, w = rgb.shape[:2]
    factor = min(1.0, MAX_SIDE / max(w, h))
    size = (max(1, round(w * factor)), max(1, round(h * factor)))
    grey = cv2.cvtColor(cv2.resize(rgb, size, interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY)
    found = cv2.createLineSegmentDetector().detect(grey)[0]
    if found is None:
        return np.zeros((0, 3)), np.zeros(0)
    ends = found.reshape(-1, 4).astype(np.float64)  # x1, y1, x2, y2
    lengths = np.hypot(ends[:, 2] - ends[:, 0], ends[:, 3] - ends[:, 1])
    keep = lengths >= max(MIN_LENGTH_PX, MIN_LENGTH_FRACTION * float(np.hypot(*size)))
    ends, lengths = ends[keep], lengths[keep]
    K = scale_intrinsics(frame.K, (frame.width, frame.height), size)
    K_inv = np.linalg.inv(K)
    ones = np.ones((len(ends), 1))
    rays_a = np.hstack([ends[:, :2], ones]) @ K_inv.T
    rays_b = np.hstack([ends[:, 2:], ones]) @ K_inv.T
    normals = np.cross(rays_a, rays_b) @ frame.pose[:3, :3].T  # camera -> world axes
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return normals, lengths


def evenly_spaced(count: int) -> np.ndarray:
    """Indices (int64, ascending) of at most MAX_PHOTOS of `count` photos, evenly spaced."""
    return np.unique(np.linspace(0, count - 1, min(MAX_PHOTOS, count)).round().astype(int))


def photo_up(normals: np.ndarray, lengths: np.ndarray, up: np.ndarray) -> Optional[np.ndarray]:
    """Up (world axes, unit (3,)) as one photo's own vertical lines measure it, or None when it shows
    too few of them, in too few directions, to pin it down. The segments' planes (`normals` (M, 3)
    unit, `lengths` (M,)) within MAX_OFF_PRIOR_DEG of `up` (3,), the whole capture's, are searched as
    `up_from_vertical_lines` searches all photos' (every pair of the PHOTO_MAX_LINES longest tried),
    then refitted on the inliers. Gravity is one direction for every photo, so a photo's up differs
    from the capture's only as far as its pose is off."""
    near = np.flatnonzero(np.abs(normals @ up) < np.sin(np.radians(MAX_OFF_PRIOR_DEG)))
    if len(near) < PHOTO_MIN_LINES:
        return None
    near = near[np.argsort(-lengths[near])[:PHOTO_MAX_LINES]]
    n, weight = normals[near], lengths[near]
    first, second = np.triu_indices(len(n), k=1)
    limit = np.sin(np.radians(PHOTO_INLIER_DEG))
    estimate = _best_up(_pair_ups(n[first], n[second], up), n, weight, limit)
    if estimate is None:
        return None
    estimate, values, inliers = _refit(n, weight, estimate, limit, up)
    # Lines all at one place in the photo have nearly one plane: they pin up down only along it.
    if inliers < PHOTO_MIN_LINES or values[1] < PHOTO_MIN_SPREAD * values.sum():
        return None
    return estimate


def _pair_ups(first: np.ndarray, second: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """(K, 3) unit ups, each the direction both of a pair of segment planes contain (normals `first`,
    `second` (P, 3)), on `prior`'s side; only pairs that pin one down (not near-parallel planes) within
    MAX_OFF_PRIOR_DEG of `prior` (3,)."""
    ups = np.cross(first, second)
    norms = np.linalg.norm(ups, axis=1)
    ups = ups[norms >= 0.2] / norms[norms >= 0.2, None]
    ups *= np.sign(ups @ prior)[:, None]
    return ups[ups @ prior >= np.cos(np.radians(MAX_OFF_PRIOR_DEG))]


def _best_up(candidates: np.ndarray, normals: np.ndarray, lengths: np.ndarray, limit: float) -> Optional[np.ndarray]:
    """The candidate up (of (K, 3)) with the longest segments whose plane (`normals` (M, 3)) holds it
    within `limit` (the sine of the inlier angle); the first such, or None without candidates."""
    if not len(candidates):
        return None
    return candidates[int(np.argmax((np.abs(candidates @ normals.T) < limit) @ lengths))]


def _refit(normals: np.ndarray, lengths: np.ndarray, up: np.ndarray, limit: float,
           prior: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """`up` refitted three times on its inlier segments (planes within `limit` of it), as the direction
    most perpendicular to their length-weighted normals: (up (3,) on `prior`'s side, the last fit's
    eigenvalues (3,) ascending, its inlier count)."""
    for _ in range(3):
        inliers = np.abs(normals @ up) < limit
        values, vectors = np.linalg.eigh((normals[inliers] * lengths[inliers, None]).T @ normals[inliers])
        up = vectors[:, 0] * np.sign(vectors[:, 0] @ prior)
    return up, values, int(inliers.sum())


def up_from_vertical_lines(frames: Sequence[Frame], prior_up: np.ndarray, seed: int = 0) -> Optional[LineGravity]:
    """Gravity's up (world axes) from the vertical lines seen by the posed `frames`, near `prior_up` (3,);
    None when too few vertical lines are seen to trust it."""
    posed = [f for f in frames if f.pose is not None and f.K is not None]
    if len(posed) < MIN_PHOTOS:
        return None
    return up_from_segments(photo_segments([posed[i] for i in evenly_spaced(len(posed))]), prior_up, seed)


def photo_segments(frames: Sequence[Frame]) -> list[tuple[np.ndarray, np.ndarray]]:
    """`segment_plane_normals` of each posed frame (normals (M, 3), lengths (M,)); none for a photo
    that cannot be read (it is reported where it matters: SfM, the fusion)."""
    segments = []
    for frame in frames:
        try:
            segments.append(segment_plane_normals(frame))
        except CaptureError:
            segments.append((np.zeros((0, 3)), np.zeros(0)))
    return segments


def up_from_segments(segments: Sequence[tuple[np.ndarray, np.ndarray]], prior_up: np.ndarray,
                     seed: int = 0) -> Optional[LineGravity]:
    """`up_from_vertical_lines` on photos' segments already found (`photo_segments`)."""
    if len(segments) < MIN_PHOTOS:
        return None
    prior = np.asarray(prior_up, dtype=np.float64) / np.linalg.norm(prior_up)
    normals, lengths, owners = [], [], []
    for index, (n, length) in enumerate(segments):
        near = np.abs(n @ prior) < np.sin(np.radians(MAX_OFF_PRIOR_DEG))
        normals.append(n[near])
        lengths.append(length[near])
        owners.append(np.full(int(near.sum()), index))
    if sum(len(n) for n in normals) < MIN_LINES:
        return None
    n, length, owner = np.concatenate(normals), np.concatenate(lengths), np.concatenate(owners)

    rng = np.random.default_rng(seed)
    pairs = np.array([rng.choice(len(n), 2, replace=False) for _ in range(RANSAC_ITERATIONS)])
    limit = np.sin(np.radians(INLIER_DEG))
    best = _best_up(_pair_ups(n[pairs[:, 0]], n[pairs[:, 1]], prior), n, length, limit)
    if best is None:
        return None
    up, _, _ = _refit(n, length, best, limit, prior)
    inliers = np.abs(n @ up) < limit
    photos = len(np.unique(owner[inliers]))
    if inliers.sum() < MIN_LINES or photos < MIN_PHOTOS:
        return None
    spread = float(np.degrees(np.sqrt(np.mean(np.arcsin(np.clip(n[inliers] @ up, -1, 1)) ** 2))))
    return LineGravity(up=up, lines=int(inliers.sum()), photos=photos, candidates=len(n), spread_deg=spread,
                       off_prior_deg=float(np.degrees(np.arccos(np.clip(up @ prior, -1.0, 1.0)))))
