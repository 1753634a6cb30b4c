"""Sanity checks on an SfM result and on given poses, turned into warnings a user can act on.

Thresholds come from the failure experiments in platform-notes section 1: a good capture of a
textured room registers (nearly) every photo in one model with a reprojection error well below
1 px and thousands of points.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Optional, Sequence

import numpy as np

from ..capture.naming import name_list
from ..errors import PoseError
from .adjust import cam_from_world_of
from .process import run_pose_job
from .refine import FEATURE_MAX_SIDE, SharedFeatures, neighbour_pairs, photo_name

if TYPE_CHECKING:
    from ..capture.model import Capture
    from ..jobs import CancelToken, ProgressCallback

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
    groups: Optional[Sequence[Sequence[int]]] = None,
    links: Sequence[tuple[int, int, int]] = (),
    frame_names: Sequence[str] = (),
) -> list[str]:
    """Warnings for a result whose largest model was kept. `groups`: each model's photos (capture
    indices into `frame_names`, the kept model first) and `links` (photo a, photo b, verified matches):
    the pairs of photos in different groups, so a split says where the photos part and how little
    linked them."""
    warnings: list[str] = []
    registered = num_images - len(unregistered)
    if registered < MIN_REGISTERED_FRACTION * num_images:
        warnings.append(
            f"only {registered} of {num_images} photos got a camera pose; not placed: "
            f"{name_list(unregistered)}. Take photos with more overlap between neighbours."
        )
    if len(model_sizes) > 1:
        warning = (f"the photos split into {len(model_sizes)} separate groups "
                   f"({', '.join(map(str, model_sizes))} photos); only the largest is used")
        if groups and frame_names:
            warning += f" ({photo_runs(groups[0], frame_names)}). " + " ".join(
                _left_out_group(group, groups[0], links, frame_names) for group in groups[1:])
        else:
            warning += ". Add photos that connect the groups."
        warnings.append(warning)
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


def min_group_size(photos: int) -> int:
    """The fewest photos a group of them (an SfM model) must have to count: a quarter of the photos,
    3 to 10 (COLMAP's default), so that a split is reported while COLMAP's strays are not."""
    return max(3, min(10, photos // 4))


def distinct_groups(groups: Sequence[Sequence[int]], min_size: int) -> list[list[int]]:
    """Models' photos (largest first) without the photos a larger model already has, and without the
    groups that leaves under `min_size`: COLMAP can return a stray model of two photos that the main
    model also poses (seen on the demo room), which is no split."""
    kept: list[list[int]] = []
    seen: set[int] = set()
    for group in groups:
        rest = [int(i) for i in group if int(i) not in seen]
        if kept and len(rest) < min_size:
            continue
        kept.append(rest)
        seen.update(rest)
    return kept


def photo_runs(indices: Sequence[int], frame_names: Sequence[str], limit: int = 3) -> str:
    """The photos `indices` (capture order) as stretches: "a to b", "a to b and c", ..."""
    ordered = sorted(set(int(i) for i in indices))
    runs: list[list[int]] = []
    for i in ordered:
        if runs and i == runs[-1][-1] + 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    words = [frame_names[r[0]] if len(r) == 1 else f"{frame_names[r[0]]} to {frame_names[r[-1]]}" for r in runs]
    return name_list(words, limit=limit).replace(" more", " more stretches")


NEAR_THE_PASSAGE = 10  # photos either side of where a left-out group and the kept one meet in capture order


def _passage(group: set[int], kept: set[int]) -> Optional[tuple[int, int]]:
    """(a, b): the consecutive photos, in capture order among the two groups' photos, where the capture
    passes from one group to the other between their longest stretches; None if it never does."""
    order = sorted(group | kept)
    runs: list[list[int]] = []  # stretches of photos of one group, in capture order
    for i in order:
        if runs and (i in group) == (runs[-1][-1] in group):
            runs[-1].append(i)
        else:
            runs.append([i])
    if len(runs) < 2:
        return None
    best = max(range(len(runs) - 1), key=lambda r: len(runs[r]) + len(runs[r + 1]))
    return runs[best][-1], runs[best + 1][0]


def _left_out_group(group: Sequence[int], kept: Sequence[int], links: Sequence[tuple[int, int, int]],
                    frame_names: Sequence[str]) -> str:
    """Where one left-out group meets the kept one in the capture, what linked them there, and where
    more photos would join them. A photo placed at a look-alike place far along the walk is in its
    group's stretches but not where the capture passes between the groups."""
    inside, used = set(int(i) for i in group), set(int(i) for i in kept)
    what = f"{photo_runs(group, frame_names)} ({len(inside)} photos) is left out"
    passage = _passage(inside, used)
    if passage is None:
        return f"{what}. Add photos that connect the groups."
    a, b = passage
    near = sorted(((x, y, n) for x, y, n in links
                   if ((x in inside and y in used) or (y in inside and x in used))
                   and a - NEAR_THE_PASSAGE <= min(x, y) and max(x, y) <= b + NEAR_THE_PASSAGE), key=lambda link: -link[2])
    where = f"where the capture passes from {frame_names[a]} to {frame_names[b]}"
    if not near:
        linked = f"{where}, no photo pair links the two groups"
    else:
        x, y, matches = near[0]
        x, y = sorted((x, y))
        pairs = "only 1 photo pair links" if len(near) == 1 else f"only {len(near)} photo pairs link"
        linked = (f"{where}, {pairs} the two groups (the best, {frame_names[x]} and {frame_names[y]}, with "
                  f"{matches} matches), too few to place one group against the other")
    return f"{what}: {linked}. Take more photos there, closer together and with texture in view."


def significant_distortion(shift_px: float, image_size: tuple[int, int]) -> bool:
    """Whether a corner shift (pixels) matters for images of image_size (width, height)."""
    return shift_px > MAX_DISTORTION_FRACTION * max(image_size)


# --- Given poses (tracker, ARKit, SLAM, RGB-D rig): do they agree with the photos? ---
#
# SIFT matches between neighbouring photos are triangulated with the given poses held fixed (the
# refinement's worker job with no adjustment round), keeping rays up to 3 deg off. Poses that agree
# with the photos reproject those points within a fraction of a pixel (the demo room's true poses:
# 0.25 px at 320 x 240; the realistic room_05001's: 0.37 px); poses off by 0.5-2 degrees, as a
# tracker can be, leave 3.7-3.9 px there. The check runs on a subset of the photos at a modest size,
# so it costs a few seconds where a full refinement costs a minute.
MIN_CHECK_FRAMES = 8  # fewer posed photos than this: too few neighbours to match, the check is skipped
POSE_CHECK_MAX_SIDE = FEATURE_MAX_SIDE  # photos downscaled to this larger side (the refinement's): the threshold is in these pixels
POSE_CHECK_MAX_FRAMES = 24  # evenly spaced frames checked (their neighbours by pose are matched)
# Mean reprojection error above which the given poses are called off, in pixels at POSE_CHECK_MAX_SIDE:
# a smaller photo's error is scaled up to that side. Judged at their own 256 px, the two ARKitScenes
# kitchens' iPad poses (0.80 and 0.85 px there, 1.5-1.6 px at 480: more than the 3D Scanner App
# corridor's 1.04 in angle) passed and were not refined; refined, their meshes' F rose 0.427 -> 0.437
# and 0.375 -> 0.415, recall 0.356 -> 0.387 and 0.318 -> 0.354 (docs/experiments.md, "Small photos'
# poses judged at the check's side").
MAX_GIVEN_POSE_ERROR_PX = 1.0
# Fewer triangulated points than this: too little to judge by. A weakly textured room gives few
# (room_05001, 24 photos at 320 x 240: 126-127 points, tracker or true poses; room_05002's tracker
# poses: 45-46 points at 1.50 px), and the mean over a few dozen points already separates 0.4 px (poses
# that fit) from 1.5-3.7 px (a tracker's). At 50, room_05002 went unjudged and kept its poses: F 0.18,
# 10,111 pieces; judged and refined, F 0.45, normals 0.74, 39 pieces. A false call costs only time:
# a refinement that is not better is refused and the given poses kept.
MIN_CHECK_POINTS = 30
REFINE_SUGGESTION = "refine them against the photos: engine reconstruct and vortx_batch.py do so unless --keep-poses, " \
                    "engine poses --refine, or Refine Poses in Blender"


@dataclass(frozen=True)
class PoseCheck:
    """How well the given poses explain the photos."""

    mean_reprojection_error_px: Optional[float]  # None when no point could be triangulated
    points: int  # points triangulated with the given poses
    frames: int  # frames checked
    image_side: int  # larger side (pixels) of the photos as checked
    poses_off: bool  # the photos say the given poses are off: refine them
    message: str  # the warning when poses_off; else why nothing could be said, or "" when they fit
    # The check's features, when it ran with a work_dir that outlives it: a refinement reuses them.
    features: Optional[SharedFeatures] = None
    # (N, 3) float64 the points triangulated with the given poses, in the capture's world (None: not kept)
    triangulated: Optional[np.ndarray] = None

    def summary(self) -> dict:
        """JSON-ready: the reconstruction sidecar's and the batch report's pose check."""
        return {"mean_reprojection_error_px": self.mean_reprojection_error_px, "points": self.points,
                "frames": self.frames, "image_side": self.image_side, "poses_off": self.poses_off,
                "message": self.message}


def check_given_poses(
    capture: "Capture",
    progress: Optional["ProgressCallback"] = None,
    cancel: Optional["CancelToken"] = None,
    max_frames: int = POSE_CHECK_MAX_FRAMES,
    max_side: int = POSE_CHECK_MAX_SIDE,
    work_dir: Optional[Path] = None,
) -> PoseCheck:
    """Triangulate matches with `capture`'s given poses and measure their reprojection error.

    Needs 3 or more posed frames with intrinsics (PoseError otherwise, as refinement does).
    """

    posed = [f for f in capture.frames if f.pose is not None and f.K is not None]
    if len(posed) < 3:
        raise PoseError(f"checking the given poses needs 3 or more posed frames with intrinsics; {capture.root} has "
                        f"{len(posed)}")
    chosen = np.unique(np.round(np.linspace(0, len(posed) - 1, min(max_frames, len(posed)))).astype(int))
    frames = [posed[i] for i in chosen]
    poses = np.stack([f.pose for f in frames])
    names = [photo_name(int(i)) for i in chosen]
    work = Path(work_dir) if work_dir else Path(tempfile.mkdtemp(prefix="vortx-pose-check-"))
    work.mkdir(parents=True, exist_ok=True)
    job = {
        "kind": "refine",
        "work_dir": str(work),
        "images": [{"path": str(f.image_path), "name": n} for f, n in zip(frames, names)],
        "max_side": int(max_side),
        "max_num_features": 4096,
        "num_threads": -1,
        "K_per_image": [np.asarray(f.K, dtype=np.float64).tolist() for f in frames],
        "cam_from_world": [cam_from_world_of(p).tolist() for p in poses],
        "pairs": [list(p) for p in neighbour_pairs(poses, 6, 2)],
        "rounds": 0,  # triangulate with the given poses only: no adjustment
        "loose_angle_deg": 3.0,
        "features_from": None,
    }
    result, xyz, _ = run_pose_job(job, work, keep_work=work_dir is not None, task="pose check", progress=progress,
                                  cancel=cancel)
    features = (SharedFeatures(work / "database.db", tuple(int(i) for i in chosen), int(max_side))
                if work_dir is not None and (work / "database.db").is_file() else None)
    error = result.get("mean_reprojection_error")
    side = min(max(max(f.width, f.height) for f in frames), max_side) if max_side > 0 else max(max(f.width, f.height) for f in frames)
    if error is None or len(xyz) < MIN_CHECK_POINTS:
        # Too little to judge by: few matches (plain surfaces) or poses so far off that nothing triangulates.
        message = (f"the given poses could not be checked against the photos: only {len(xyz)} points could be "
                   f"triangulated with them from {len(frames)} photos; if the result looks doubled or blurred, "
                   f"{REFINE_SUGGESTION}")
        return PoseCheck(None if error is None else float(error), int(len(xyz)), len(frames), int(side), False, message,
                         features, xyz)
    # The threshold is in pixels at the check's side: photos smaller than that are judged as if enlarged
    # to it, so the same angular error is called off at every photo size.
    judged_side = max_side if max_side > 0 else side  # side never exceeds max_side
    judged = float(error) * judged_side / side
    if judged > MAX_GIVEN_POSE_ERROR_PX:
        at = f"{side} px" if judged_side == side else f"{side} px, {judged:.2f} px at {judged_side} px"
        message = (f"the given poses look off: points triangulated with them reproject {error:.2f} px from where the "
                   f"photos show them (mean over {len(xyz)} points at {at}; poses that fit give under "
                   f"{MAX_GIVEN_POSE_ERROR_PX:g} px at {judged_side} px), so surfaces will come out doubled or blurred; "
                   f"{REFINE_SUGGESTION}")
        return PoseCheck(float(error), int(len(xyz)), len(frames), int(side), True, message, features, xyz)
    return PoseCheck(float(error), int(len(xyz)), len(frames), int(side), False, "", features, xyz)
