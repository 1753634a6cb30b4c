"""Refine given camera poses against the photos (tracker, ARKit, SLAM or RGB-D rig poses a little off).

Stereo and fusion need poses good to a fraction of a degree; trackers are often off by a few
tenths of a degree to 2 degrees, or by a fixed offset between the colour and the tracking camera.
Their camera centres, though, carry the capture's scale, and bundle adjustment with a free gauge
rescales weakly linked stretches of a trajectory (the SUN3D study room's first stretch by 13-19 %).
So `refine_poses` takes the given poses as the gauge, as COLMAP's "known poses" recipe and OpenMVS do:
1. only the frames reconstruction uses: the keyframes of a metric capture (`select_keyframes`, the
   reconstruction's own rule), each paired with its neighbours by pose and in capture order;
2. in the COLMAP worker process (`sfm_worker_refine.py`, kind "refine": a COLMAP abort must not take
   Blender down): SIFT features (at a lower contrast threshold on dim or plain photos), matches for
   those pairs, one triangulation with the given poses that keeps tracks as far off as the poses may
   be (`expected_error_deg`, COLMAP's own filter included), so tracks of three or more views survive
   for the adjustment to turn the cameras by (optionally a second triangulation with the turned ones);
3. bundle adjustment here (`adjust.py`): rotations, one focal scale per intrinsics group and the
   points, camera centres held at the given ones; then, as a second pass (`stretches.py`), the centres
   free within a tight prior around the given ones, stretch by stretch: a stretch of the trajectory
   that it would rescale by more than `max_stretch_scale_change` keeps the first pass's poses, the
   others take the free centres when that lowers their reprojection error measurably; keyframes the
   triangulation left out are posed from the points their neighbours see (`resect.py`);
4. judged before it is used: unless the refined poses explain the photos better than the given ones
   (mean reprojection error lower by `min_gain`), the given poses are kept and the result says so;
5. frames between keyframes follow their neighbouring keyframes' corrections (interpolated in
   capture order); each frame's change is measured against its given pose. A frame that turned more
   than `max_rotation_deg` (or moved more than the translation limit) keeps its given pose and is
   listed as refused; keyframes the photos could not constrain keep theirs and are listed as not
   refined. When too many are refused, the refinement as a whole is refused with PoseError.

Public API (the CLI's `engine poses --refine`, `engine reconstruct`, Blender and the batch call this):
- `refine_poses(capture, options=None, progress=None, cancel=None) -> RefineResult`;
- `RefineOptions`, `RefineResult` (capture, changes per frame, stretch scales, errors before and
  after, timings per stage, `report`), `FrameChange`; `StretchScale` (`stretches.py`).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..capture.model import Capture, Frame
from ..capture.naming import name_list
from ..errors import PoseError
from ..geometry.view_selection import DEFAULT_KEYFRAME_ANGLE_DEG, DEFAULT_KEYFRAME_TRANSLATION_M, select_keyframes
from ..jobs import CancelToken, ProgressCallback, check, report
from .adjust import AdjustOptions, Tracks, adjust, cam_from_world_of, cam_to_world_of, log_rotations, rodrigues
from .align import rotation_angle_deg
from .process import run_pose_job
from .resect import Resection, resect_left_out
from .stretches import StretchScale, free_centres, stretch_scales

STATUS_REFINED = "refined"
STATUS_REFUSED = "refused"
STATUS_NOT_REFINED = "not refined"

# The photos' larger side for the pose check's and the refinement's SIFT features. Measured on the
# SUN3D room (docs/experiments.md): depth within 5 % after refinement 0.41 at 640 px, 0.46 at 480,
# 0.44 at 320; SIFT at 480 costs 0.3-0.4 of 640's. 1.5-2.5x what stereo matches at (200-320 px).
FEATURE_MAX_SIDE = 480

PASS_HELD = "camera positions held"
PASS_PRIORS = "camera positions within priors"


@dataclass
class RefineOptions:
    # Downscale photos so their larger side is at most this (0 = full size); the pose check's size, so
    # its features serve here too.
    max_side: int = FEATURE_MAX_SIDE
    # "keyframes": a metric capture's keyframes are adjusted and the frames between follow them;
    # "all": every posed frame is adjusted (captures in arbitrary units always use all).
    frames: str = "keyframes"
    keyframe_translation: float = DEFAULT_KEYFRAME_TRANSLATION_M  # the reconstruction's keyframe rule
    keyframe_angle_deg: float = DEFAULT_KEYFRAME_ANGLE_DEG
    # ... plus the frames kept at 1/densify of those thresholds (see frames_to_adjust). Measured on the
    # SUN3D room (docs/experiments.md): 3 (39 of 99 frames) 0.32 of the depth within 5 %, 6 (58) 0.40,
    # every frame 0.39.
    densify: float = 6.0
    neighbours: int = 8  # frames each frame is matched with, chosen by pose (nearby, looking the same way)
    sequential_neighbours: int = 3  # and the next frames in capture order
    expected_error_deg: float = 3.0  # the triangulation tolerates given poses this far off
    # COLMAP's fixed-pose adjustment inside the triangulation filters at the same tolerance instead of
    # its own 4 px. On room_05001 (tracker poses 0.5-2 deg off, 320 x 240) 10 -> 28 of 40 frames
    # refined (rotation error against the truth 1.47 -> 0.83 deg median); on the real SUN3D room the
    # extra, looser tracks turned the cameras further (4.1 deg median instead of 3.0) and the default
    # reconstruction lost F (Room 0.496 -> 0.433, Off 0.40 -> 0.33): off until a rule tells the two apart.
    loose_filter: bool = False
    # Then triangulate the matches again with the rotations a first adjustment found, at this tolerance
    # (0: COLMAP's own, 2 deg and 4 px), and adjust again from the given poses. Off: once the first
    # triangulation keeps tracks as far off as the poses (the worker's filter at the same tolerance),
    # the second round found no more: room_05001 (tracker poses, 320 x 240) 30 of 40 frames refined
    # either way, rotation error against the truth 0.80 deg median vs 0.85; SUN3D 99 of 99 either way,
    # at 1.4x the time.
    retriangulate: bool = False
    retriangulation_error_deg: float = 0.0
    # Second pass: camera centres free within this prior (metres for metric captures, else a share of
    # the trajectory's extent / 100 per unit); 0 skips the pass. Each stretch of the trajectory (split
    # at jumps) whose scale the free centres change by more than `max_stretch_scale_change` keeps the
    # first pass's poses; the others take the free ones, when that lowers their reprojection error by
    # `min_position_gain`. Measured (docs/experiments.md, "Camera centres freed stretch by stretch"):
    # the 200-frame render's rotation error against its truth 0.87 -> 0.66 deg median, centres 1.9 ->
    # 1.2 cm off, F 0.720 -> 0.772; SUN3D's second stretch's depth maps 0.75-0.80 -> 0.83-0.88 within 5 %
    # while its first, weakly linked stretch (rescaled 1.2 % when freed, its maps 0.39-0.53) keeps its
    # poses. Freed everywhere, the first stretch's maps fell and SUN3D's F with them: hence by stretch.
    position_sigma_m: float = 0.05
    min_position_gain: float = 0.1  # a freed stretch is kept only when it lowers its cameras' error by this share
    max_stretch_scale_change: float = 0.005  # ... and the stretch's scale changes by no more than this
    # The free pass solves for 6 unknowns a camera instead of 3, in a dense (6C)^2 system: 500 cameras
    # are 72 MB a matrix; beyond that the centres stay as given (a note says so).
    max_free_frames: int = 500
    # One focal scale per group of frames sharing intrinsics. Off: on the SUN3D room it moved the focal
    # 0.8-1.5 % for a 0.3 % lower reprojection error, too weakly determined to trust over a calibration.
    refine_focal: bool = False
    min_gain: float = 0.1  # refined poses must lower the mean reprojection error by this share, else the given stay
    max_rotation_deg: float = 10.0  # a frame turning more than this is refused (keeps its given pose)
    max_translation_m: float = 0.5  # ... or moving more than this, for metric captures
    max_translation_fraction: float = 0.1  # ... or, in arbitrary units, this share of the trajectory's extent
    # A frame seeing fewer triangulated points (that two other frames also see) is not refined. With
    # its centre held a frame has 3 unknowns, so 10 points over-determine it sevenfold.
    min_points: int = 10
    max_refused_share: float = 0.25  # refuse the whole refinement when more frames than this are refused
    max_num_features: int = 8192  # SIFT features per photo
    num_threads: int = -1  # -1: all cores
    work_dir: Optional[Path] = None  # keep the worker's files (database, log) here; default: temporary, deleted
    # The pose check's features (quality.check_given_poses with a work_dir) on the same capture at the
    # same max_side: its photos join the adjusted frames and are not extracted again.
    features_from: Optional["SharedFeatures"] = None


@dataclass(frozen=True)
class SharedFeatures:
    """A COLMAP database with the features (and matches) of some posed frames, named by `photo_name`."""

    database: Path
    posed_indices: tuple[int, ...]  # the frames it has, as indices into the capture's posed frames
    max_side: int  # the size their photos were downscaled to


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
    mean_reprojection_error: float  # px of the photos refinement ran on, with the poses returned
    error_given_px: float  # ... with the given poses (points fitted to them), on the same observations
    scaled_size: tuple[int, int]  # (width, height) of those photos
    adjusted_frames: int  # frames bundle adjustment ran on (keyframes); the others followed them
    adjustment: str  # PASS_HELD or PASS_PRIORS: what the returned poses come from
    focal_scale: list[float]  # per intrinsics group, 1 = as given
    stretches: list[StretchScale] = field(default_factory=list)
    kept_given: str = ""  # why the given poses were kept (the refinement did not help); "" when refined
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

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

    def _focal_scales(self) -> str:
        """Each intrinsics group's focal scale, or their range where there are many (a phone's ARKit
        export has its own intrinsics per photo)."""
        scales = np.asarray(self.focal_scale, np.float64)
        if len(scales) <= 4:
            return ", ".join(f"{s:.4f}" for s in scales)
        return f"{scales.min():.4f}..{scales.max():.4f} over {len(scales)} intrinsics groups"

    @property
    def report(self) -> str:
        total = len(self.changes)
        lines = [
            f"Pose refinement: triangulation with the given poses + bundle adjustment ({self.adjustment}) of "
            f"{self.adjusted_frames} frames, photos at {self.scaled_size[0]}x{self.scaled_size[1]}",
            f"  reprojection error {self.error_given_px:.2f} px with the given poses, {self.mean_reprojection_error:.2f} px "
            f"refined ({len(self.points)} 3D points); focal scale {self._focal_scales()}",
        ]
        if self.kept_given:
            lines.append(f"  kept the given poses: {self.kept_given}")
        else:
            lines.append(
                f"  refined {len(self.refined)} of {total} posed frames: rotation changed by {self.rotation_deg_median:.2f} deg "
                f"median, {self.rotation_deg_max:.2f} deg max; position by {_length(self.translation_median, self.units)} "
                f"median, {_length(self.translation_max, self.units)} max")
        lines += [f"  {s.describe()}" for s in self.stretches]
        for change in self.changes:
            if change.status != STATUS_REFINED and not self.kept_given:
                lines.append(f"  {change.status}: {change.name} ({change.reason}); it keeps its given pose")
        if self.timings:
            lines.append("  time: " + ", ".join(f"{k} {v:.1f} s" for k, v in self.timings.items()))
        lines += [f"  note: {n}" for n in self.notes]
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


def frames_to_adjust(poses_c2w: np.ndarray, metric: bool, options: RefineOptions) -> np.ndarray:
    """Indices (K,) into `poses_c2w` (N, 4, 4) of the frames bundle adjustment runs on.

    A metric capture: the reconstruction's keyframes (its own rule and thresholds, so each is adjusted
    itself, not interpolated) plus the frames the same rule keeps at `1 / densify` of the thresholds
    (neighbours that tie the keyframes together with longer tracks); else every frame. Always the
    first and the last frame, so every other frame lies between two adjusted ones."""
    if options.frames not in ("keyframes", "all"):
        raise ValueError(f"RefineOptions.frames must be 'keyframes' or 'all', got {options.frames!r}")
    count = len(poses_c2w)
    if options.frames == "all" or not metric:
        return np.arange(count)
    keyframes = select_keyframes(poses_c2w, options.keyframe_translation, options.keyframe_angle_deg)
    density = max(1.0, float(options.densify))
    neighbours = select_keyframes(poses_c2w, options.keyframe_translation / density, options.keyframe_angle_deg / density)
    return np.unique(np.concatenate([keyframes, neighbours, [0, count - 1]])).astype(np.int64)


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
    given = np.stack([f.pose for f in frames]).astype(np.float64)
    chosen = frames_to_adjust(given, capture.metric, options)
    shared = options.features_from
    if shared is not None and (shared.max_side != options.max_side or not Path(shared.database).is_file()
                               or max(shared.posed_indices, default=0) >= len(frames)):
        shared = None  # features of another size (or another capture) cannot be reused
    if shared is not None:
        chosen = np.union1d(chosen, np.asarray(shared.posed_indices, dtype=np.int64))
    names = [photo_name(int(k)) for k in chosen]
    work = Path(options.work_dir) if options.work_dir else Path(tempfile.mkdtemp(prefix="vortx-refine-"))
    work.mkdir(parents=True, exist_ok=True)
    job = {
        "kind": "refine",
        "work_dir": str(work),
        "images": [{"path": str(frames[k].image_path), "name": n} for k, n in zip(chosen, names)],
        "max_side": int(options.max_side),
        "max_num_features": int(options.max_num_features),
        "num_threads": int(options.num_threads),
        "K_per_image": [np.asarray(frames[k].K, dtype=np.float64).tolist() for k in chosen],
        "cam_from_world": [cam_from_world_of(given[k]).tolist() for k in chosen],
        "pairs": [list(p) for p in neighbour_pairs(given[chosen], options.neighbours, options.sequential_neighbours)],
        "loose_angle_deg": float(options.expected_error_deg),
        "loose_filter": bool(options.loose_filter),
        "features_from": str(shared.database) if shared is not None else None,
    }
    keep = options.work_dir is not None
    try:
        result, xyz, rgb = run_pose_job(job, work, keep_work=keep or options.retriangulate, task="pose refinement",
                                        progress=progress, cancel=cancel)
        check(cancel)
        if options.retriangulate and result.get("tracks") is not None and len(xyz):
            result, xyz, rgb = _retriangulated(job, work, frames, given, chosen, result, xyz, options, progress, cancel)
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)
    check(cancel)
    return _adjusted(capture, posed_index, given, chosen, result, xyz, rgb, options, progress)


def _retriangulated(job: dict, work: Path, frames: list[Frame], given: np.ndarray, chosen: np.ndarray, result: dict,
                    xyz: np.ndarray, options: RefineOptions, progress: Optional[ProgressCallback],
                    cancel: Optional[CancelToken]) -> tuple[dict, np.ndarray, np.ndarray]:
    """Triangulate the first round's matches again, with the rotations a first adjustment of its tracks
    found and COLMAP's own tolerances (2 deg, 4 px): the loose first round admits wrong matches and
    misses tracks its poses left too far apart; with the cameras turned into place the tracks come out
    longer and cleaner. Returns the second round's (result, points, colours), timings of both.

    job: the first round's worker job (in `work`); frames, given (N, 4, 4), chosen (K,): as `_adjusted`."""
    start = time.perf_counter()
    sx, sy = result["scale"]
    Ks = np.stack([np.diag([sx, sy, 1.0]) @ np.asarray(frames[k].K, dtype=np.float64) for k in chosen])
    found = result["tracks"]
    first = adjust(Ks, _intrinsic_groups(Ks), np.stack([cam_from_world_of(given[k]) for k in chosen]),
                   Tracks(found["obs_image"], found["obs_point"], found["obs_uv"], xyz),
                   AdjustOptions(position_sigma=None, refine_focal=options.refine_focal))
    first_time = time.perf_counter() - start
    check(cancel)
    second_work = work / "retriangulated"
    second_work.mkdir(parents=True, exist_ok=True)
    # The first round's database, features and matches, is reused: only the triangulation runs again.
    database = work / "round1.db"
    shutil.copyfile(work / "database.db", database)
    features = work / "database_features.json"
    if features.is_file():
        shutil.copyfile(features, work / "round1_features.json")
    second_job = dict(job, work_dir=str(second_work), cam_from_world=[p.tolist() for p in first.cam_from_world],
                      loose_angle_deg=float(options.retriangulation_error_deg), features_from=str(database))
    second, xyz2, rgb2 = run_pose_job(second_job, second_work, keep_work=True, task="pose refinement",
                                      progress=progress, cancel=cancel)
    timings = {k: float(v) for k, v in result["timings"].items()}
    timings["first adjust"] = first_time
    timings["retriangulate"] = sum(float(v) for v in second["timings"].values())
    second["timings"] = timings
    second["first_round"] = {"points": int(len(xyz)), "observations": int(len(found["obs_image"]))}
    return second, xyz2, rgb2


def photo_name(posed_index: int) -> str:
    """The worker's name for the capture's posed frame `posed_index` (the pose check names them alike,
    so a refinement can reuse the check's features)."""
    return f"{posed_index:06d}.jpg"


def _intrinsic_groups(Ks: np.ndarray) -> np.ndarray:
    """(C,) int: cameras with the same K share a group (one focal scale)."""
    groups = np.zeros(len(Ks), dtype=np.int64)
    seen: list[np.ndarray] = []
    for c, K in enumerate(Ks):
        for g, other in enumerate(seen):
            if np.allclose(K, other, rtol=1e-6, atol=1e-6):
                groups[c] = g
                break
        else:
            groups[c] = len(seen)
            seen.append(K)
    return groups


def _adjusted(
    capture: Capture,
    posed_index: list[int],
    given: np.ndarray,
    chosen: np.ndarray,
    result: dict,
    xyz: np.ndarray,
    rgb: np.ndarray,
    options: RefineOptions,
    progress: Optional[ProgressCallback] = None,
) -> RefineResult:
    """Adjust the triangulated tracks with the given centres as the gauge, judge, and apply to every frame.

    given: (N, 4, 4) camera-to-world of the posed frames; chosen: (K,) indices into them that the
    worker triangulated (its image k is frame chosen[k]); result/xyz/rgb: the worker's output.
    """
    frames = [capture.frames[i] for i in posed_index]
    units = "m" if capture.metric else "units"
    timings = {k: float(v) for k, v in result["timings"].items()}
    tracks_found = result.get("tracks")
    if tracks_found is None or len(xyz) == 0:
        raise PoseError(_unconstrained_message(capture, 0, len(chosen), result))
    sx, sy = result["scale"]
    Ks = np.stack([np.diag([sx, sy, 1.0]) @ np.asarray(frames[k].K, dtype=np.float64) for k in chosen])
    groups = _intrinsic_groups(Ks)
    cam_from_world = np.stack([cam_from_world_of(given[k]) for k in chosen])
    tracks = Tracks(tracks_found["obs_image"], tracks_found["obs_point"], tracks_found["obs_uv"], xyz)
    keypoint_of = np.asarray(tracks_found.get("obs_keypoint", np.full(len(tracks.camera), -1)), dtype=np.int64)
    start_tracks = tracks

    start = time.perf_counter()
    report(progress, "poses: bundle adjustment", 0, 2)
    held = adjust(Ks, groups, cam_from_world, tracks, AdjustOptions(position_sigma=None, refine_focal=options.refine_focal))
    seen = _points_seen_with_others(tracks, held.inlier, len(chosen))
    constrained = seen >= options.min_points
    if constrained.sum() < 3:
        raise PoseError(_unconstrained_message(capture, int(constrained.sum()), len(chosen), result))
    extent = float(np.max(np.linalg.norm(given[:, None, :3, 3] - given[None, :, :3, 3], axis=-1)))
    chosen_given = given[chosen]
    best, adjustment, stretches = held, PASS_HELD, stretch_scales(frames, chosen, chosen_given, held, tracks, constrained)
    notes: list[str] = []
    if options.position_sigma_m > 0 and len(chosen) > options.max_free_frames:
        notes.append(f"camera positions kept as given: {len(chosen)} adjusted frames are more than the "
                     f"{options.max_free_frames} whose positions the second pass frees (memory)")
    elif options.position_sigma_m > 0:
        report(progress, "poses: bundle adjustment", 1, 2)
        sigma = options.position_sigma_m if capture.metric else options.position_sigma_m * extent / 100.0
        second = free_centres(Ks, groups, held, tracks, frames, chosen, chosen_given, constrained, sigma,
                              options.max_stretch_scale_change, options.refine_focal)
        start_tracks = second.tracks
        if not second.freed.any():
            notes.append(f"camera positions kept as given: freeing them within {_length(sigma, units)} would rescale "
                         f"every stretch by more than {100 * options.max_stretch_scale_change:g} %")
        elif second.gain < options.min_position_gain:
            notes.append(f"camera positions kept as given: freeing them within {_length(sigma, units)} lowered the "
                         f"reprojection error only from {second.error_held_px:.2f} to {second.error_free_px:.2f} px")
        else:
            free = second.adjusted
            free.error_given_px = held.error_given_px  # the given poses' error on the first pass's observations
            best, adjustment, stretches = free, PASS_PRIORS, second.stretches
            if not second.freed.all():
                kept = [frames[int(c)].name for c in chosen[~second.freed]]
                notes.append(f"camera positions kept as given for {len(kept)} frame(s) ({kept[0]} .. {kept[-1]}): "
                             f"freeing them would rescale their stretch by more than "
                             f"{100 * options.max_stretch_scale_change:g} %")
    report(progress, "poses: bundle adjustment", 2, 2)
    timings["adjust"] = time.perf_counter() - start
    start = time.perf_counter()
    resected = resect_left_out(Ks, best, tracks if best is held else start_tracks,
                               keypoint_of if best is held else keypoint_of[held.inlier], result.get("matches"),
                               constrained, chosen_given, options.min_points, options.max_rotation_deg)
    timings["resect"] = time.perf_counter() - start
    if resected:
        notes.append(f"{len(resected)} frame(s) that too few triangulated points constrain were posed from the points "
                     "their refined neighbours see (rotation solved, centre kept)")

    kept_given = ""
    if not best.error_adjusted_px <= (1.0 - options.min_gain) * best.error_given_px:
        kept_given = (f"the refined poses explain the photos no better: {best.error_adjusted_px:.2f} px mean reprojection "
                      f"error against {best.error_given_px:.2f} px with the given ones (a gain under "
                      f"{100 * options.min_gain:.0f} %)")
    adjusted_c2w = np.stack([cam_to_world_of(p) for p in best.cam_from_world])
    return _apply(capture, posed_index, given, chosen, adjusted_c2w, constrained, seen, resected, best, adjustment,
                  stretches, kept_given, notes, units, extent, Ks, groups, xyz, rgb, timings, result, options)


def _points_seen_with_others(tracks: Tracks, inlier: np.ndarray, cameras: int) -> np.ndarray:
    """(C,) per camera: its inlier observations of points that two other cameras also see. A point seen
    from two views fits any pair of poses (the two rays meet wherever they are), so only longer tracks
    say whether a camera's pose agrees with the others: a frame given a pose 30 deg off sees many of
    the first kind and few of the second."""
    length = np.bincount(tracks.point[inlier], minlength=len(tracks.points))
    shared = inlier & (length[tracks.point] >= 3)
    return np.bincount(tracks.camera[shared], minlength=cameras)


def _unconstrained_message(capture: Capture, constrained: int, total: int, result: dict) -> str:
    return (f"pose refinement failed: only {constrained} of {total} frames of {capture.root} could be "
            f"constrained by the photos ({result.get('num_points3D', 0)} points triangulated, "
            f"{result['database']['verified_pairs']} matched photo pairs). The given poses may not belong to these "
            "photos (another axis convention?), or the photos overlap too little; reconstruct with the given poses, "
            "or estimate new ones with structure from motion (engine poses)")


def follow_keyframes(given_c2w: np.ndarray, chosen: np.ndarray, adjusted_c2w: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses of every frame: the adjusted ones at `chosen`, the others corrected like their
    neighbouring adjusted frames in capture order (the camera-frame rotation correction interpolated
    on the sphere, the centre shift linearly), which a tracker's slowly drifting error allows.

    given_c2w: (N, 4, 4); chosen: (K,) increasing indices, containing 0 and N - 1; adjusted_c2w: (K, 4, 4).
    """
    count = len(given_c2w)
    out = given_c2w.copy()
    correction = np.einsum("kji,kjl->kil", given_c2w[chosen, :3, :3], adjusted_c2w[:, :3, :3])  # R_given^T R_adjusted
    shift = adjusted_c2w[:, :3, 3] - given_c2w[chosen, :3, 3]
    out[chosen] = adjusted_c2w
    position = np.searchsorted(chosen, np.arange(count))
    for i in np.setdiff1d(np.arange(count), chosen):
        b = int(position[i])
        a = b - 1
        t = (i - chosen[a]) / (chosen[b] - chosen[a])
        relative = correction[a].T @ correction[b]
        w = log_rotations(relative)[0]
        step = correction[a] @ rodrigues((t * w)[None])[0]
        out[i, :3, :3] = given_c2w[i, :3, :3] @ step
        out[i, :3, 3] = given_c2w[i, :3, 3] + (1 - t) * shift[a] + t * shift[b]
    return out


def _apply(capture: Capture, posed_index: list[int], given: np.ndarray, chosen: np.ndarray, adjusted_c2w: np.ndarray,
           constrained: np.ndarray, seen: np.ndarray, resected: dict[int, Resection], best, adjustment: str,
           stretches: list[StretchScale],
           kept_given: str, notes: list[str], units: str, extent: float, Ks: np.ndarray, groups: np.ndarray,
           xyz: np.ndarray, rgb: np.ndarray, timings: dict[str, float], result: dict,
           options: RefineOptions) -> RefineResult:
    """Every posed frame's refined pose (or its given one), the changes, the acceptance rules."""
    frames = [capture.frames[i] for i in posed_index]
    max_translation = options.max_translation_m if capture.metric else options.max_translation_fraction * extent
    kept = best.constrained_points
    points, colors = best.points[kept], np.asarray(rgb, dtype=np.uint8).reshape(-1, 3)[kept]
    common = dict(units=units, points=points, point_colors=colors, mean_reprojection_error=best.error_adjusted_px,
                  error_given_px=best.error_given_px, scaled_size=_scaled_size(frames[0], options.max_side),
                  adjusted_frames=len(chosen), adjustment=adjustment, focal_scale=[float(v) for v in best.focal_scale],
                  stretches=stretches, timings=timings, notes=notes)
    if kept_given:
        changes = [FrameChange(f.name, 0.0, 0.0, STATUS_NOT_REFINED, "the given poses were kept") for f in frames]
        return RefineResult(capture=capture, changes=changes, kept_given=kept_given,
                            warnings=[f"pose refinement kept the given poses: {kept_given}"], **common)

    reasons: dict[int, str] = {}
    adjusted_c2w = adjusted_c2w.copy()
    for k in np.flatnonzero(~constrained):
        adjusted_c2w[k] = given[chosen[k]]
        if int(k) in resected:
            adjusted_c2w[k, :3, :3] = resected[int(k)].rotation.T
            continue
        reasons[int(chosen[k])] = (f"it sees {int(seen[k])} triangulated points that two other photos also see, fewer "
                                   f"than {options.min_points}, and too few of the points its refined neighbours see")
    everyone = follow_keyframes(given, chosen, adjusted_c2w)
    focal_of = {}
    for k, g in zip(chosen, groups):
        focal_of.setdefault(int(g), np.asarray(frames[int(k)].K, dtype=np.float64))

    frame_changes: list[FrameChange] = []
    new_frames = list(capture.frames)
    for n, frame in enumerate(frames):
        if n in reasons:
            frame_changes.append(FrameChange(frame.name, 0.0, 0.0, STATUS_NOT_REFINED, reasons[n]))
            continue
        rotation, translation = _change(everyone[n], given[n])
        if rotation > options.max_rotation_deg or translation > max_translation:
            reason = (f"refinement moved it by {rotation:.1f} deg and {_length(translation, units)}, beyond the "
                      f"{options.max_rotation_deg:g} deg / {_length(max_translation, units)} limit")
            frame_changes.append(FrameChange(frame.name, rotation, translation, STATUS_REFUSED, reason))
            continue
        frame_changes.append(FrameChange(frame.name, rotation, translation, STATUS_REFINED))
        new_frames[posed_index[n]] = replace(frame, pose=everyone[n], K=_scaled_focal(frame.K, focal_of, best.focal_scale))

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
    return RefineResult(capture=capture.with_frames(new_frames), changes=frame_changes, warnings=warnings, **common)


def _scaled_focal(K: np.ndarray, focal_of: dict[int, np.ndarray], focal_scale: np.ndarray) -> np.ndarray:
    """K with its focal lengths scaled by its intrinsics group's focal scale (unchanged when no group has its K)."""
    for group, reference in focal_of.items():
        if np.allclose(K, reference, rtol=1e-6, atol=1e-6):
            scaled = np.array(K, dtype=np.float64)
            scaled[0, 0] *= focal_scale[group]
            scaled[1, 1] *= focal_scale[group]
            return scaled
    return K


def _change(refined_c2w: np.ndarray, given_c2w: np.ndarray) -> tuple[float, float]:
    """(rotation degrees, centre distance) between two camera-to-world poses (4, 4)."""
    rotation = rotation_angle_deg(given_c2w[:3, :3].T @ refined_c2w[:3, :3])
    return rotation, float(np.linalg.norm(refined_c2w[:3, 3] - given_c2w[:3, 3]))


def _scaled_size(frame: Frame, max_side: int) -> tuple[int, int]:
    factor = min(1.0, max_side / max(frame.width, frame.height)) if max_side > 0 else 1.0
    return max(1, round(frame.width * factor)), max(1, round(frame.height * factor))
