"""Refine given camera poses against the photos (tracker, ARKit, SLAM or RGB-D rig poses a little off).

Stereo and fusion need poses good to a fraction of a degree; trackers are often off by a few
tenths of a degree to 2 degrees, or by a fixed offset between the colour and the tracking camera.
`refine_poses` keeps the given poses as the starting point and:
1. pairs each frame with its neighbours, in capture order and by pose (nearby cameras looking the
   same way: they share most of the view);
2. in the COLMAP worker process (`sfm_worker.py`, kind "refine": a COLMAP abort must not take
   Blender down): SIFT features, matches for those pairs, triangulation with the given poses and
   intrinsics (held fixed), bundle adjustment, retriangulation, ... until the poses settle;
3. brings the adjusted trajectory back to the given poses' world (gravity, origin and metric scale)
   with a similarity fit (`align.fit_pose_similarity`, robust: frames that moved too far are left
   out of the fit);
4. measures each frame's change against its given pose. A frame that moved more than
   `max_rotation_deg` or the translation limit looks like a failure (or a wrong given pose): it
   keeps its given pose and is listed as refused; frames the photos could not constrain (too few
   triangulated points) keep theirs and are listed as not refined. When too many frames are
   refused, the refinement as a whole is refused with PoseError (the numbers and what to do).

Public API (the CLI's `engine poses --refine`, `engine reconstruct --refine-poses`, Blender and the
batch script call this):
- `refine_poses(capture, options=None, progress=None, cancel=None) -> RefineResult`;
- `RefineOptions` (max_side, neighbours, sequential_neighbours, expected_error_deg, rounds,
  max_rotation_deg, max_translation_m, max_translation_fraction, min_points, max_refused_share,
  max_num_features, num_threads, work_dir);
- `RefineResult`: capture (same frames in the same order; refined poses where accepted), changes
  (`FrameChange` per posed frame: name, rotation_deg, translation, status "refined" | "refused" |
  "not refined", reason), refined / refused / not_refined (names), rotation_deg_median/_max and
  translation_median/_max (over refined frames), units ("m" or "units"), points (N, 3) and
  point_colors (N, 3) uint8 in the capture's world, mean_reprojection_error (px of the photos
  refinement ran on), rounds, timings, warnings, and `report` (lines for the CLI / Blender console).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..capture.model import Capture, Frame
from ..capture.naming import name_list
from ..errors import PoseError
from ..jobs import CancelToken, ProgressCallback, check
from .align import Similarity, fit_pose_similarity, rotation_angle_deg
from .process import run_pose_job

STATUS_REFINED = "refined"
STATUS_REFUSED = "refused"
STATUS_NOT_REFINED = "not refined"


@dataclass
class RefineOptions:
    max_side: int = 1024  # downscale photos so their larger side is at most this; 0 = full size
    neighbours: int = 8  # frames each frame is matched with, chosen by pose (nearby, looking the same way)
    sequential_neighbours: int = 3  # and the next frames in capture order
    expected_error_deg: float = 3.0  # the first triangulation tolerates given poses this far off
    rounds: int = 6  # most triangulate + bundle adjustment rounds (stops earlier once the poses settle)
    max_rotation_deg: float = 10.0  # a frame turning more than this is refused (keeps its given pose)
    max_translation_m: float = 0.5  # ... or moving more than this, for metric captures
    max_translation_fraction: float = 0.1  # ... or, in arbitrary units, this share of the trajectory's extent
    min_points: int = 30  # a frame seeing fewer triangulated points is not refined
    max_refused_share: float = 0.25  # refuse the whole refinement when more frames than this are refused
    max_num_features: int = 8192  # SIFT features per photo
    num_threads: int = -1  # -1: all cores
    work_dir: Optional[Path] = None  # keep the worker's files (database, log) here; default: temporary, deleted


@dataclass(frozen=True)
class FrameChange:
    name: str
    rotation_deg: float  # angle between the given and the refined camera orientation
    translation: float  # distance between the given and the refined camera centre (RefineResult.units)
    status: str  # "refined" | "refused" | "not refined"
    reason: str = ""  # why it was refused or not refined


@dataclass
class RefineResult:
    capture: Capture  # the given capture with refined poses where accepted (same frames, same order)
    changes: list[FrameChange]  # one per posed frame, in capture order
    units: str  # "m" for metric captures, else "units" (the capture's own)
    points: np.ndarray  # (N, 3) float64 triangulated points in the capture's world
    point_colors: np.ndarray  # (N, 3) uint8 RGB
    mean_reprojection_error: float  # pixels of the photos refinement ran on
    scaled_size: tuple[int, int]  # (width, height) of those photos
    rounds: int
    similarity: Similarity  # adjusted world -> given world
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def _names(self, status: str) -> list[str]:
        return [c.name for c in self.changes if c.status == status]

    @property
    def refined(self) -> list[str]:
        return self._names(STATUS_REFINED)

    @property
    def refused(self) -> list[str]:
        return self._names(STATUS_REFUSED)

    @property
    def not_refined(self) -> list[str]:
        return self._names(STATUS_NOT_REFINED)

    def _stat(self, attribute: str, reduce) -> float:
        values = [getattr(c, attribute) for c in self.changes if c.status == STATUS_REFINED]
        return float(reduce(values)) if values else 0.0

    @property
    def rotation_deg_median(self) -> float:
        return self._stat("rotation_deg", np.median)

    @property
    def rotation_deg_max(self) -> float:
        return self._stat("rotation_deg", np.max)

    @property
    def translation_median(self) -> float:
        return self._stat("translation", np.median)

    @property
    def translation_max(self) -> float:
        return self._stat("translation", np.max)

    @property
    def report(self) -> str:
        total = len(self.changes)
        lines = [
            f"Pose refinement: pycolmap triangulation + bundle adjustment from the given poses, photos at "
            f"{self.scaled_size[0]}x{self.scaled_size[1]}, {self.rounds} rounds",
            f"  refined {len(self.refined)} of {total} posed frames: rotation changed by {self.rotation_deg_median:.2f} deg "
            f"median, {self.rotation_deg_max:.2f} deg max; position by {_length(self.translation_median, self.units)} "
            f"median, {_length(self.translation_max, self.units)} max",
            f"  mean reprojection error {self.mean_reprojection_error:.2f} px, {len(self.points)} 3D points",
        ]
        for change in self.changes:
            if change.status != STATUS_REFINED:
                lines.append(f"  {change.status}: {change.name} ({change.reason}); it keeps its given pose")
        if self.timings:
            lines.append("  time: " + ", ".join(f"{k} {v:.1f} s" for k, v in self.timings.items()))
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def _length(value: float, units: str) -> str:
    return f"{100 * value:.1f} cm" if units == "m" else f"{value:.3g} {units}"


def neighbour_pairs(poses_c2w: np.ndarray, neighbours: int, sequential: int) -> list[tuple[int, int]]:
    """Image pairs (i < j) to match: `sequential` next frames in order, plus each frame's
    `neighbours` best by pose: nearby centres and similar viewing directions (within 75 deg).

    poses_c2w: (N, 4, 4) camera-to-world, OpenCV axes (z forward).
    """
    count = len(poses_c2w)
    pairs: set[tuple[int, int]] = set()
    for i in range(count):
        for j in range(i + 1, min(count, i + 1 + sequential)):
            pairs.add((i, j))
    centres = poses_c2w[:, :3, 3]
    forward = poses_c2w[:, :3, 2]
    spread = float(np.median(np.linalg.norm(centres - centres.mean(0), axis=1))) or 1.0
    distance = np.linalg.norm(centres[:, None] - centres[None], axis=-1) / spread
    angle = np.degrees(np.arccos(np.clip(forward @ forward.T, -1.0, 1.0)))
    # One unit of trajectory spread costs as much as 45 degrees of turning.
    cost = distance + angle / 45.0
    cost[angle > 75.0] = np.inf
    np.fill_diagonal(cost, np.inf)
    for i in range(count):
        for j in np.argsort(cost[i])[:neighbours]:
            if np.isfinite(cost[i, j]):
                pairs.add((min(i, int(j)), max(i, int(j))))
    return sorted(pairs)


def refine_poses(
    capture: Capture,
    options: Optional[RefineOptions] = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
) -> RefineResult:
    """Refine the posed frames of `capture` against its photos; see the module docstring.

    Frames without a pose are left as they are. Raises PoseError when the capture cannot be refined
    (fewer than 3 posed frames, a posed frame without intrinsics, no triangulated points) or when the
    result looks like a failure; Cancelled when `cancel` fires.
    """
    options = options or RefineOptions()
    posed_index = [i for i, f in enumerate(capture.frames) if f.pose is not None]
    if len(posed_index) < 3:
        raise PoseError(f"pose refinement needs at least 3 posed frames, {capture.root} has {len(posed_index)}")
    frames = [capture.frames[i] for i in posed_index]
    missing_K = [f.name for f in frames if f.K is None]
    if missing_K:
        raise PoseError(f"pose refinement needs the intrinsics of every posed frame; {name_list(missing_K)} have none")
    check(cancel)
    given = np.stack([f.pose for f in frames])
    names = [f"{i:06d}.jpg" for i in range(len(frames))]
    work = Path(options.work_dir) if options.work_dir else Path(tempfile.mkdtemp(prefix="vortx-refine-"))
    work.mkdir(parents=True, exist_ok=True)
    job = {
        "kind": "refine",
        "work_dir": str(work),
        "images": [{"path": str(f.image_path), "name": n} for f, n in zip(frames, names)],
        "max_side": int(options.max_side),
        "max_num_features": int(options.max_num_features),
        "num_threads": int(options.num_threads),
        "K_per_image": [np.asarray(f.K, dtype=np.float64).tolist() for f in frames],
        "cam_from_world": [_cam_from_world(p).tolist() for p in given],
        "pairs": [list(p) for p in neighbour_pairs(given, options.neighbours, options.sequential_neighbours)],
        "rounds": int(options.rounds),
        "loose_angle_deg": float(options.expected_error_deg),
    }
    result, xyz, rgb = run_pose_job(job, work, keep_work=options.work_dir is not None, task="pose refinement",
                                    progress=progress, cancel=cancel)
    return _accepted(capture, posed_index, given, names, result, xyz, rgb, options)


def _cam_from_world(c2w: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world -> COLMAP's (3, 4) world-to-camera [R^T | -R^T t]."""
    rotation = c2w[:3, :3].T
    return np.hstack([rotation, (-rotation @ c2w[:3, 3])[:, None]])


def _cam_to_world(cam_from_world: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = cam_from_world[:, :3].T
    pose[:3, 3] = -cam_from_world[:, :3].T @ cam_from_world[:, 3]
    return pose


def _accepted(
    capture: Capture,
    posed_index: list[int],
    given: np.ndarray,
    names: list[str],
    result: dict,
    xyz: np.ndarray,
    rgb: np.ndarray,
    options: RefineOptions,
) -> RefineResult:
    """Fit the adjusted trajectory to the given one, measure each frame's change, accept or refuse."""
    frames = [capture.frames[i] for i in posed_index]
    by_name = {im["name"]: im for im in result["images"]}
    units = "m" if capture.metric else "units"
    extent = float(np.max(np.linalg.norm(given[:, None, :3, 3] - given[None, :, :3, 3], axis=-1)))
    max_translation = options.max_translation_m if capture.metric else options.max_translation_fraction * extent

    adjusted: dict[int, np.ndarray] = {}
    reasons: dict[int, str] = {}
    for k, name in enumerate(names):
        image = by_name.get(name)
        seen = 0 if image is None else int(image["num_points3D"])
        if seen < options.min_points:
            reasons[k] = f"it sees {seen} triangulated points, fewer than {options.min_points}"
        else:
            adjusted[k] = _cam_to_world(np.asarray(image["cam_from_world"], dtype=np.float64))
    if len(adjusted) < 3:
        raise PoseError(
            f"pose refinement failed: only {len(adjusted)} of {len(names)} frames of {capture.root} could be "
            f"constrained by the photos ({result['num_points3D']} points triangulated, "
            f"{result['database']['verified_pairs']} matched photo pairs). The given poses may not belong to these "
            "photos (another axis convention?), or the photos overlap too little; reconstruct with the given poses, "
            "or estimate new ones with structure from motion (engine poses)"
        )

    # Robust fit: all constrained frames, then only those whose change stays within the limits.
    inliers = sorted(adjusted)
    similarity = Similarity.identity()
    changes: dict[int, tuple[float, float]] = {}
    for _ in range(3):
        similarity = fit_pose_similarity(np.stack([adjusted[k] for k in inliers]), given[inliers])
        changes = {k: _change(similarity.apply_pose(adjusted[k]), given[k]) for k in adjusted}
        within = [k for k, (rot, move) in changes.items() if rot <= options.max_rotation_deg and move <= max_translation]
        if len(within) < 3 or within == inliers:
            break
        inliers = within

    frame_changes: list[FrameChange] = []
    new_frames = list(capture.frames)
    for k, frame in enumerate(frames):
        if k not in adjusted:
            frame_changes.append(FrameChange(frame.name, 0.0, 0.0, STATUS_NOT_REFINED, reasons[k]))
            continue
        rotation, translation = changes[k]
        if rotation > options.max_rotation_deg or translation > max_translation:
            reason = (f"refinement moved it by {rotation:.1f} deg and {_length(translation, units)}, beyond the "
                      f"{options.max_rotation_deg:g} deg / {_length(max_translation, units)} limit")
            frame_changes.append(FrameChange(frame.name, rotation, translation, STATUS_REFUSED, reason))
            continue
        frame_changes.append(FrameChange(frame.name, rotation, translation, STATUS_REFINED))
        new_frames[posed_index[k]] = replace(frame, pose=similarity.apply_pose(adjusted[k]))

    refused = [c for c in frame_changes if c.status == STATUS_REFUSED]
    if len(refused) > options.max_refused_share * len(frames) or len(frames) - len(refused) < 3:
        rot = np.array([c.rotation_deg for c in frame_changes if c.status != STATUS_NOT_REFINED])
        move = np.array([c.translation for c in frame_changes if c.status != STATUS_NOT_REFINED])
        raise PoseError(
            f"pose refinement refused: {len(refused)} of {len(frames)} frames of {capture.root} would move beyond "
            f"{options.max_rotation_deg:g} deg or {_length(max_translation, units)} (rotation change median "
            f"{np.median(rot):.1f} deg, max {rot.max():.1f} deg; position change median {_length(float(np.median(move)), units)}, "
            f"max {_length(float(move.max()), units)}; worst: {name_list([c.name for c in refused])}). Such changes "
            "mean the photos and the given poses disagree (wrong axis convention or frame order, a moving scene, "
            "or too little overlap); reconstruct with the given poses, or estimate new ones with structure from "
            "motion (engine poses)"
        )

    warnings: list[str] = []
    if refused:
        warnings.append(f"{len(refused)} frame(s) would have moved too far and keep their given pose: "
                        f"{name_list([c.name for c in refused])}")
    not_refined = [c.name for c in frame_changes if c.status == STATUS_NOT_REFINED]
    if not_refined:
        warnings.append(f"{len(not_refined)} frame(s) could not be refined (too few matched points) and keep their "
                        f"given pose: {name_list(not_refined)}")
    points = similarity.apply_points(xyz) if len(xyz) else np.zeros((0, 3))
    refined_capture = capture.with_frames(new_frames)
    return RefineResult(
        capture=refined_capture,
        changes=frame_changes,
        units=units,
        points=points,
        point_colors=np.asarray(rgb, dtype=np.uint8).reshape(-1, 3),
        mean_reprojection_error=float(result["mean_reprojection_error"] or 0.0),
        scaled_size=_scaled_size(frames[0], options.max_side),
        rounds=int(result["rounds"]),
        similarity=similarity,
        timings={k: float(v) for k, v in result["timings"].items()},
        warnings=warnings,
    )


def _change(refined_c2w: np.ndarray, given_c2w: np.ndarray) -> tuple[float, float]:
    """(rotation degrees, centre distance) between two camera-to-world poses (4, 4)."""
    rotation = rotation_angle_deg(given_c2w[:3, :3].T @ refined_c2w[:3, :3])
    return rotation, float(np.linalg.norm(refined_c2w[:3, 3] - given_c2w[:3, 3]))


def _scaled_size(frame: Frame, max_side: int) -> tuple[int, int]:
    factor = min(1.0, max_side / max(frame.width, frame.height)) if max_side > 0 else 1.0
    return max(1, round(frame.width * factor)), max(1, round(frame.height * factor))
