"""Capture preparation: a loaded capture -> the posed, Z-up, metric world the network needs.

The one step shared by `python -m engine reconstruct`, `python -m engine poses`, Blender's Import
Capture / Estimate Poses / Reconstruct and the batch script, so the same capture gives the same world
through each of them:
- photos without poses get structure from motion (which aligns and scales its own model with the
  sparse points), when the caller allows it;
- posed captures in arbitrary units (COLMAP, most transforms.json) are rotated Z up and, where a
  floor can be found, scaled from the camera height (`align_gravity_and_scale`);
- metric layouts (ScanNet, metric transforms.json) pass through untouched;
- with `refine=True`, given poses (tracker, ARKit, SLAM, RGB-D rig) are first refined against the
  photos (`refine.refine_poses`: triangulation with the given poses, bundle adjustment that keeps
  their camera centres, so the capture's scale); its triangulated points then serve the floor search
  of the alignment. Poses that
  structure from motion just estimated are not refined again (bundle adjustment already did it).

`PreparedCapture` says what was done (scale source, one-line description, warnings), so every entry
point reports it in the same words.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..capture.model import Capture
from ..errors import PoseError
from ..jobs import CancelToken, ProgressCallback
from .. import poses as pose_package  # estimate_poses, refine_poses looked up at call time: tests stand in for them
from .camera_height import DEFAULT_CAMERA_HEIGHT_M
from .align import Similarity
from .gravity import KnownDistance, align_gravity_and_scale, rescale_capture
from .quality import MIN_CHECK_FRAMES, PoseCheck, check_given_poses
from .refine import STATUS_NOT_REFINED, STATUS_REFUSED, RefineOptions, RefineResult
from .scale import SOURCE_GUESS, ScaleEstimate, estimate_metric_scale
from .sfm import PoseResult, SfmOptions

# When structure from motion runs.
SFM_NEVER = "never"  # posed frames are aligned, unposed captures are returned as they are (Blender import)
SFM_IF_UNPOSED = "if unposed"  # SfM only when no frame has a pose (engine reconstruct)
SFM_ALWAYS = "always"  # SfM replaces any poses the capture has (engine poses, Estimate Poses)
SFM_MODES = (SFM_NEVER, SFM_IF_UNPOSED, SFM_ALWAYS)

# PreparedCapture.scale_source values, beside align_gravity_and_scale's own
# ("camera height", "known distance", "metric capture", "unknown").
NO_POSES = "no poses"


@dataclass
class PreparedCapture:
    capture: Capture  # posed frames Z up (metres when the scale is known); unposed captures as given
    scale_source: str  # "camera height", "known distance", "metric capture", "unknown", "no poses"
    description: str  # one line: what was done to the world
    warnings: list[str] = field(default_factory=list)
    sfm: Optional["PoseResult"] = None  # the structure-from-motion result when SfM ran (its report, points)
    # What moved the given posed frames from the capture's own frame into this world (x_world = s R x_capture + t),
    # every step here composed into it (Z up, floor, scale); None when SfM replaced them or there were none.
    # The one source of the capture <-> world mapping that results record (engine/recon/output_frame.py).
    similarity: Optional[Similarity] = None
    # The refinement of the given poses when it ran (per-frame changes, refused frames, its points in
    # the refined capture's world before the alignment above).
    refinement: Optional["RefineResult"] = None
    # Sparse points (N, 3) in the prepared world with their colours (N, 3) uint8: SfM's or the
    # refinement's; None when neither ran.
    points: Optional[np.ndarray] = None
    point_colors: Optional[np.ndarray] = None
    notes: list[str] = field(default_factory=list)  # what was done that is no problem (refinement not needed)
    # The metric scale from the floor and ceiling (scale.py) when the camera-height guess was replaced
    # by it; scale_source is then its source ("floor and ceiling", ...).
    scale: Optional["ScaleEstimate"] = None
    # How well the given poses explain the photos (quality.check_given_poses), when they were checked.
    pose_check: Optional["PoseCheck"] = None

    @property
    def ran_sfm(self) -> bool:
        return self.sfm is not None

    @property
    def report_lines(self) -> list[str]:
        """What the entry points print (CLI) or log (Blender console): the SfM report when SfM ran,
        else the one-line description of the world."""
        if self.sfm is not None:
            scale = [f"  scale: {self.scale.describe()}"] if self.scale is not None else []
            return self.sfm.report.splitlines() + scale + [f"note: {n}" for n in self.notes]
        lines = self.refinement.report.splitlines() if self.refinement is not None else []
        return lines + [f"poses: {self.description}"] + [f"note: {n}" for n in self.notes]

    def moved(self, tolerance: float = 1e-5) -> bool:
        """True when the given poses were changed: refined, or moved by more than `tolerance` (metres
        at 1 m from the origin, radians, relative scale); False when SfM replaced them (a new world,
        not a move)."""
        if self.refinement is not None and self.refinement.refined:
            return True
        if self.similarity is None:
            return False
        s = self.similarity
        return bool(abs(s.scale - 1.0) > tolerance or abs(s.rotation - np.eye(3)).max() > tolerance
                    or abs(s.translation).max() > tolerance)

    def summary(self) -> dict:
        """What preparation did, as JSON-ready data: the reconstruction sidecar's and the batch
        report's "poses" entry."""
        source = "structure from motion" if self.ran_sfm else ("none" if self.scale_source == NO_POSES else "given")
        entry: dict = {"source": source, "refined": self.refinement is not None, "scale_source": self.scale_source,
                       "description": self.description, "warnings": list(self.warnings), "notes": list(self.notes)}
        if self.refinement is not None:
            entry["refinement"] = refinement_summary(self.refinement)
        if self.scale is not None:
            entry["scale"] = self.scale.summary()
        if self.pose_check is not None:
            entry["pose_check"] = self.pose_check.summary()
        if self.sfm is not None:
            entry["features"] = self.sfm.features
        return entry

    def pose_status(self) -> str:
        """The Blender panel's one-line pose status: how many frames are posed, by what, at which scale."""
        capture = self.capture
        posed, total = len(capture.posed_frames), len(capture.frames)
        if posed == 0:
            return "No poses: run Estimate Poses"
        scale = {
            "camera height": "scaled by camera height",
            "known distance": "scaled by a known distance",
            "metric capture": "metric",
        }.get(self.scale_source, "scale unknown")
        if self.scale is not None:
            scale = f"scaled by the {self.scale.source}, +-{100 * self.scale.relative_sigma:.0f} %"
        if self.ran_sfm:
            return f"{posed} of {total} posed by SfM, {scale}"
        origin = capture.pose_origin or capture.format  # "ARKit (3D Scanner App)" says more than a format name
        status = f"All {total} posed ({origin})" if posed == total else f"{posed} of {total} posed ({origin})"
        return f"{status}, metric" if self.scale_source == "metric capture" else f"{status}, Z up, {scale}"


def prepare_capture(
    capture: Capture,
    camera_height: float = DEFAULT_CAMERA_HEIGHT_M,
    known_distance: Optional[KnownDistance] = None,
    sfm: str = SFM_IF_UNPOSED,
    sfm_options: Optional["SfmOptions"] = None,
    refine: bool = False,
    refine_options: Optional["RefineOptions"] = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    check_poses: bool = False,
    refine_when_off: bool = False,
) -> PreparedCapture:
    """`capture` in the world the network needs: posed, Z up, metric where a scale can be found.

    `sfm` (one of SFM_MODES) says when structure from motion runs; `sfm_options` tunes it (its own
    camera_height / known_distance are replaced by the arguments here, so the scale has one source).
    `refine` refines the given poses against the photos first (`refine_options` tunes it); it is a
    note, not an error, when SfM estimated the poses here (already adjusted) or none are given.
    `check_poses` checks given poses that are not refined against the photos (a few seconds of
    matching); poses that look off get a warning suggesting refinement, or, with `refine_when_off`,
    are refined right away (the check and what moved are recorded; stereo and colours then use them).
    Raises PoseError for a bad camera height or known distance, when SfM finds no poses, or when the
    refinement fails or looks like a failure (its message has the numbers).
    """
    if sfm not in SFM_MODES:
        raise ValueError(f"sfm must be one of {SFM_MODES}, got {sfm!r}")
    if not camera_height > 0:
        raise PoseError(f"camera height must be positive, got {camera_height} m")
    posed = bool(capture.posed_frames)
    if sfm == SFM_ALWAYS or (sfm == SFM_IF_UNPOSED and not posed):
        prepared = _with_sfm(capture, camera_height, known_distance, sfm_options, progress, cancel)
        # Photos only: the camera-height guess is replaced by the floor and ceiling, found in dense depth.
        prepared = _with_metric_scale(prepared, camera_height, dense=True, progress=progress, cancel=cancel)
        if refine:
            prepared.notes.append(REFINE_AFTER_SFM_NOTE)
        return prepared
    if not posed:
        prepared = PreparedCapture(capture, NO_POSES, "no frame has a pose: run structure from motion (Estimate Poses)")
        if refine:
            prepared.notes.append("no frame has a pose, so there is nothing to refine")
        return prepared
    refinement = None
    points, colors = capture.points, capture.point_colors  # the capture's own (a COLMAP model's points3D)
    # When poses found off will be refined, the check keeps its features for the refinement.
    check_dir = Path(tempfile.mkdtemp(prefix="vortx-pose-check-")) if check_poses and refine_when_off and not refine else None
    try:
        check, check_note = (_check_given_poses(capture, progress, cancel, check_dir) if check_poses and not refine
                             else (None, None))
        refined_because_off = bool(refine_when_off and check is not None and check.poses_off)
        if refine or refined_because_off:
            options = refine_options or RefineOptions()
            if check is not None and check.features is not None and options.features_from is None:
                options = replace(options, features_from=check.features)
            refinement = pose_package.refine_poses(capture, options, progress=progress, cancel=cancel)
            capture = refinement.capture
            if len(refinement.points):
                points, colors = refinement.points, refinement.point_colors
    finally:
        if check_dir is not None:
            shutil.rmtree(check_dir, ignore_errors=True)
    # The sparse points (the capture's own, or the refinement's triangulated ones) let the alignment
    # find the floor of a non-metric capture; they move with the poses.
    alignment = align_gravity_and_scale(capture, camera_height=camera_height, known_distance=known_distance,
                                        points=points)
    warnings = (list(refinement.warnings) if refinement is not None else []) + list(alignment.warnings)
    aligned = alignment.capture.with_points(alignment.points, colors)
    prepared = PreparedCapture(aligned, alignment.scale_source, alignment.description, warnings,
                               similarity=alignment.similarity, refinement=refinement, points=alignment.points,
                               point_colors=colors)
    prepared.pose_check = check
    if check_note:
        prepared.notes.append(check_note)
    if refined_because_off:
        assert check is not None and check.mean_reprojection_error_px is not None and refinement is not None
        if refinement.kept_given:
            prepared.notes.append(f"the given poses disagreed with the photos ({check.mean_reprojection_error_px:.2f} px "
                                  f"mean reprojection error), but refining them did not help, so they are used as given")
        else:
            prepared.notes.append(f"the given poses disagreed with the photos ({check.mean_reprojection_error_px:.2f} px "
                                  f"mean reprojection error), so they were refined before reconstruction ({KEEP_POSES_HINT})")
    elif check is not None and check.poses_off:
        prepared.warnings.append(check.message)
    elif check is not None and check.message:
        prepared.notes.append(check.message)
    # Given non-metric poses (a COLMAP model): the floor and ceiling in its sparse points only, so
    # importing a capture stays quick.
    return _with_metric_scale(prepared, camera_height, dense=False, progress=progress, cancel=cancel)


REFINE_AFTER_SFM_NOTE = ("pose refinement skipped: structure from motion estimated these poses just now and its "
                         "bundle adjustment already fitted them to the photos")


def refinement_summary(result: "RefineResult") -> dict:
    """A refinement's report as JSON-ready data: counts, change median/max, refused frames and why."""
    return {
        "refined": len(result.refined),
        "posed_frames": len(result.changes),
        "units": result.units,
        "rotation_deg_median": result.rotation_deg_median,
        "rotation_deg_max": result.rotation_deg_max,
        "translation_median": result.translation_median,
        "translation_max": result.translation_max,
        "refused": {c.name: c.reason for c in result.changes if c.status == STATUS_REFUSED},
        "not_refined": {c.name: c.reason for c in result.changes if c.status == STATUS_NOT_REFINED},
        "points": int(len(result.points)),
        "mean_reprojection_error_px": result.mean_reprojection_error,
        "given_reprojection_error_px": result.error_given_px,
        "adjusted_frames": result.adjusted_frames,
        "adjustment": result.adjustment,
        "focal_scale": list(result.focal_scale),
        "stretch_scales": [{"kind": s.kind, "first": s.first, "last": s.last, "frames": s.frames, "scale": s.scale}
                           for s in result.stretches],
        "kept_given": result.kept_given,
        "timings_s": dict(result.timings),
    }


def _with_sfm(
    capture: Capture,
    camera_height: float,
    known_distance: Optional[KnownDistance],
    sfm_options: Optional["SfmOptions"],
    progress: Optional[ProgressCallback],
    cancel: Optional[CancelToken],
) -> PreparedCapture:
    options = replace(sfm_options or SfmOptions(), align=True, camera_height=camera_height, known_distance=known_distance)
    result = pose_package.estimate_poses(capture, options, progress=progress, cancel=cancel)
    alignment = result.alignment
    assert alignment is not None  # align=True above
    capture = result.capture.with_points(result.points, result.point_colors)  # not the given capture's old points
    return PreparedCapture(capture, alignment.scale_source, alignment.description, list(result.warnings), sfm=result,
                           points=result.points, point_colors=result.point_colors)


KEEP_POSES_HINT = "--keep-poses, or Keep Given Poses in Blender, uses them as given"
# The --keep-poses flag of `engine reconstruct` and the batch.
KEEP_POSES_HELP = ("use the capture's own poses as given, even when the check against the photos finds them off "
                   "(by default such poses are refined before stereo, and the report says what moved)")


def _check_given_poses(capture: Capture, progress: Optional[ProgressCallback], cancel: Optional[CancelToken],
                       work_dir: Optional[Path] = None) -> tuple[Optional["PoseCheck"], Optional[str]]:
    """Check the given poses of `capture` against its photos: the check, or None and a note saying why
    they could not be checked (too few posed photos, COLMAP could not run: the poses are used as given).
    With `work_dir` the check's files stay there (its features serve a refinement)."""
    checkable = [f for f in capture.frames if f.pose is not None and f.K is not None]
    if len(checkable) < MIN_CHECK_FRAMES:
        return None, (f"the given poses were not checked against the photos: {len(checkable)} posed photos "
                      f"with intrinsics, the check needs {MIN_CHECK_FRAMES}")
    try:
        return check_given_poses(capture, progress=progress, cancel=cancel, work_dir=work_dir), None
    except PoseError as error:
        return None, f"the given poses could not be checked against the photos: {error}"


def _with_metric_scale(
    prepared: PreparedCapture,
    camera_height: float,
    dense: bool,
    progress: Optional[ProgressCallback],
    cancel: Optional[CancelToken],
) -> PreparedCapture:
    """`prepared` rescaled by the floor and ceiling (scale.py) when the camera-height guess set its
    scale; a known distance, a metric capture or an unknown scale stay as they are."""
    if prepared.scale_source != "camera height":
        return prepared

    estimate = estimate_metric_scale(prepared.capture, prepared.points, camera_height, dense=dense, progress=progress,
                                     cancel=cancel)
    rescaled = rescale_capture(prepared.capture, estimate.factor, prepared.points)
    prepared.capture, prepared.points = rescaled.capture, rescaled.points
    if prepared.similarity is not None:
        prepared.similarity = prepared.similarity.then(Similarity(np.eye(3), np.zeros(3), estimate.factor))
    prepared.scale, prepared.scale_source = estimate, estimate.source
    prepared.description = f"{estimate.describe()}; {prepared.description}"
    if estimate.source == SOURCE_GUESS and not any("no floor" in w for w in prepared.warnings):
        prepared.warnings.append(f"no floor seen, so the scale is the {camera_height:g} m camera-height guess "
                                 f"(+-{100 * estimate.relative_sigma:.0f} %): check a size, or set the scale from a "
                                 "known distance (Set Scale, --known-distance)")
    prepared.notes.extend(estimate.notes)
    return prepared
