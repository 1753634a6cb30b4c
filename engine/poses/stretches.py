"""The scale of a refined trajectory's stretches, and the second pass that frees camera centres by them.

Bundle adjustment with free camera centres rescales weakly linked stretches of a trajectory (the
SUN3D study room's first stretch by 13-19 %), which is why the refinement's first pass holds the
given centres (`refine.py`). Its second pass frees them within a tight prior around the given ones
(`free_centres`), stretch by stretch: a stretch (frames between jumps in capture order) whose scale
the free centres change by more than the refinement's `max_stretch_scale_change` is adjusted again
with its centres held; the others keep the free centres. `stretch_scales` measures each stretch's
(and each covisible group's) scale against the given centres for the report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..capture.model import Frame
from .adjust import Adjusted, AdjustOptions, Tracks, adjust, cam_to_world_of, reprojection_errors
from .align import umeyama

# A stretch that keeps its given centres in the second pass: its prior's sigma times this (5 cm -> 0.01 mm).
HELD_SIGMA_SHARE = 2e-4


@dataclass(frozen=True)
class StretchScale:
    """A part of the trajectory and the scale of its refined camera centres against the given ones."""

    kind: str  # "stretch": frames between jumps in capture order; "group": frames linked by shared points
    first: str  # name of its first frame
    last: str  # name of its last frame
    frames: int  # adjusted frames in it
    scale: float  # similarity scale, refined -> given centres (1 = the given scale kept)

    def describe(self) -> str:
        return f"{self.kind} {self.first}..{self.last} ({self.frames} frames): scale {self.scale:.3f}"


@dataclass
class FreedCentres:
    """The second pass: camera centres free within their priors where their stretch keeps its scale."""

    adjusted: Adjusted  # the adjustment with the freed centres (the others held)
    tracks: Tracks  # what it adjusted: the first pass's inlier observations and its points
    freed: np.ndarray  # (C,) bool, the cameras whose stretch kept its scale with free centres
    stretches: list[StretchScale]  # the scale of each stretch and group with the freed centres
    error_held_px: float  # the freed cameras' mean reprojection error with the first pass's poses
    error_free_px: float  # ... and with the freed centres

    @property
    def gain(self) -> float:
        """The share by which freeing lowered the freed cameras' error (0 when they have none)."""
        return 1.0 - self.error_free_px / self.error_held_px if self.error_held_px > 0 else 0.0


def free_centres(Ks: np.ndarray, groups: np.ndarray, held: Adjusted, tracks: Tracks, frames: list[Frame],
                 chosen: np.ndarray, chosen_given: np.ndarray, constrained: np.ndarray, sigma: float,
                 max_scale_change: float, refine_focal: bool) -> FreedCentres:
    """The second pass from the first's (`held`, on `tracks`): centres free within `sigma` of the given
    ones, and where that rescales a stretch by more than `max_scale_change`, that stretch held.

    frames, chosen (K,), chosen_given (K, 4, 4), constrained (K,): as `stretch_scales`."""
    start_tracks = Tracks(tracks.camera[held.inlier], tracks.point[held.inlier], tracks.uv[held.inlier], held.points)
    free = adjust(Ks, groups, held.cam_from_world, start_tracks,
                  AdjustOptions(position_sigma=sigma, refine_focal=refine_focal))
    freed = stretches_in_scale(chosen_given, free, constrained, max_scale_change)
    if 0 < freed.sum() < len(freed):
        # The stretches the free centres rescale keep the first pass's poses: adjusted again with those
        # held (priors a 5,000th of the free ones) and the others free as before. Held centres alone
        # are not enough: the held stretch then turns about its line of centres (SUN3D: 2.5 deg,
        # every depth 2-3 % deeper).
        held_share = np.where(freed, 1.0, HELD_SIGMA_SHARE)
        free = adjust(Ks, groups, held.cam_from_world, start_tracks,
                      AdjustOptions(position_sigma=sigma * held_share,
                                    rotation_sigma_deg=AdjustOptions.rotation_sigma_deg * held_share,
                                    refine_focal=refine_focal))
    stretches = stretch_scales(frames, chosen, chosen_given, free, start_tracks, constrained)
    before_px, after_px = _freed_errors(Ks, groups, held, free, start_tracks, freed)
    return FreedCentres(free, start_tracks, freed, stretches, before_px, after_px)


def stretch_scales(frames: list[Frame], chosen: np.ndarray, given_c2w: np.ndarray, adjusted, tracks: Tracks,
                   constrained: np.ndarray) -> list[StretchScale]:
    """Scale of the adjusted camera centres against the given ones, per stretch (split where the capture
    jumps: a step over 10x the median step) and per connected group (frames linked by 20 or more
    shared inlier points), for parts of 3 or more constrained frames."""
    refined_c2w = np.stack([cam_to_world_of(p) for p in adjusted.cam_from_world])
    parts = [("stretch", part) for part in _stretch_parts(given_c2w)]
    parts += [("group", part) for part in _covisible_groups(tracks, adjusted.inlier, len(chosen))]
    scales: list[StretchScale] = []
    seen: set[tuple[int, ...]] = set()
    for kind, part in parts:
        part = part[constrained[part]]
        key = tuple(part.tolist())
        if len(part) < 3 or (kind == "group" and key in seen):
            continue
        seen.add(key)
        # Umeyama on the centres alone: its scale is the ratio of the centres' spreads, what a stretch
        # changing size would change (the orientation-based fit would mix the cameras' turns into it).
        fit = umeyama(refined_c2w[part, :3, 3], given_c2w[part, :3, 3])
        scales.append(StretchScale(kind, frames[int(chosen[part[0]])].name, frames[int(chosen[part[-1]])].name,
                                   len(part), float(fit.scale)))
    return scales


def _freed_errors(Ks: np.ndarray, groups: np.ndarray, held: Adjusted, free: Adjusted, tracks: Tracks,
                  freed: np.ndarray) -> tuple[float, float]:
    """Mean reprojection error (px) of the freed cameras' observations with the held and with the free
    centres, each pass with its own points (`tracks`: the first pass's inliers; those the free pass kept).
    (0, 0) when no freed camera has one."""
    mine = freed[tracks.camera] & free.inlier
    if not mine.any():
        return 0.0, 0.0
    before = reprojection_errors(Ks, held.focal_scale, groups, held.cam_from_world, held.points, tracks)[mine]
    after = reprojection_errors(Ks, free.focal_scale, groups, free.cam_from_world, free.points, tracks)[mine]
    return float(np.mean(before)), float(np.mean(after))


def _stretch_parts(given_c2w: np.ndarray) -> list[np.ndarray]:
    """Indices of the stretches of a trajectory (C, 4, 4): split where it jumps, a step over 10x the median step."""
    centres = given_c2w[:, :3, 3]
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    cut = np.flatnonzero(steps > 10.0 * max(float(np.median(steps)) if len(steps) else 0.0, 1e-9)) + 1
    return np.split(np.arange(len(centres)), cut)


def stretches_in_scale(given_c2w: np.ndarray, adjusted, constrained: np.ndarray, max_change: float) -> np.ndarray:
    """(C,) bool: cameras in a stretch (3 or more constrained frames) whose adjusted centres keep the given
    scale within `max_change`; the others' stretches were rescaled (or are too short to tell)."""
    refined = np.stack([cam_to_world_of(p) for p in adjusted.cam_from_world])[:, :3, 3]
    keep = np.zeros(len(given_c2w), dtype=bool)
    for part in _stretch_parts(given_c2w):
        measured = part[constrained[part]]
        if len(measured) >= 3 and abs(umeyama(refined[measured], given_c2w[measured, :3, 3]).scale - 1.0) <= max_change:
            keep[part] = True
    return keep


def _covisible_groups(tracks: Tracks, inlier: np.ndarray, cameras: int, min_shared: int = 20) -> list[np.ndarray]:
    """Connected components (sorted camera indices) of the graph linking cameras that share >= min_shared points."""
    camera, point = tracks.camera[inlier], tracks.point[inlier]
    order = np.argsort(point, kind="stable")
    camera, point = camera[order], point[order]
    shared = np.zeros((cameras, cameras), dtype=np.int64)
    starts = np.flatnonzero(np.r_[True, point[1:] != point[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], len(point)]):
        members = np.unique(camera[a:b])
        shared[np.ix_(members, members)] += 1
    linked = shared >= min_shared
    label = -np.ones(cameras, dtype=np.int64)
    groups = []
    for seed in range(cameras):
        if label[seed] >= 0:
            continue
        stack, label[seed], members = [seed], len(groups), [seed]
        while stack:
            c = stack.pop()
            for other in np.flatnonzero(linked[c] & (label < 0)):
                label[other] = len(groups)
                members.append(int(other))
                stack.append(int(other))
        groups.append(np.array(sorted(members), dtype=np.int64))
    return groups
