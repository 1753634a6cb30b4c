"""The Estimate Poses and Refine Poses jobs, as bpy-free job functions.

Estimate Poses: structure from motion, gravity and scale. Refine Poses: the given poses (tracker,
ARKit, SLAM) refined against the photos, in the world they are in (`engine.poses.refine_poses`).

The settings are copied out of `scene.vortx` on the main thread (`PoseSettings.from_scene`), because
the worker thread must never read Blender data. The capture is the one Import Capture loaded, when
this session still has it (`capture.loaded_capture`); otherwise it is loaded from disk.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import bpy

from ..engine import capture as engine_capture
from ..engine import poses as engine_poses  # its functions looked up at call time: tests stand in for them
from ..engine.capture import Capture
from ..engine.jobs import CancelToken, ProgressCallback
from ..engine.poses.prepare import SFM_ALWAYS, PreparedCapture, prepare_capture, refinement_summary
from ..engine.poses.refine import STATUS_REFINED
from .cameras import move_capture_cameras
from .capture import scene_camera_height
from .jobs import JobFunction
from .point_cloud import apply_point_cloud, checked_points, find_point_cloud
from .properties import POSES_KEPT, POSES_REFINED

if TYPE_CHECKING:
    from ..engine.poses import RefineOptions, RefineResult


@dataclass(frozen=True)
class PoseSettings:
    capture_path: Path
    matcher: str  # "auto" | "sequential" | "exhaustive"
    features: str  # engine.poses.sfm.FEATURES
    max_image_side: int
    camera_height: float

    @staticmethod
    def from_scene(settings: object) -> "PoseSettings":
        return PoseSettings(
            capture_path=Path(bpy.path.abspath(settings.capture_path)),
            matcher=settings.sfm_matcher.lower(),
            features=settings.sfm_features.lower(),
            max_image_side=int(settings.sfm_max_image_side),
            camera_height=scene_camera_height(settings),
        )


@dataclass(frozen=True)
class PosedCapture:
    prepared: PreparedCapture  # the SfM result, aligned and scaled
    capture_path: Path
    loaded: Capture  # the capture SfM started from (as loaded), kept for a later Estimate Poses

    @property
    def capture(self) -> Capture:
        return self.prepared.capture

    @property
    def report(self) -> str:
        """The engine's multi-line SfM report, for the console."""
        return "\n".join(self.prepared.report_lines)

    @property
    def warnings(self) -> list[str]:
        return self.prepared.warnings

    def pose_status(self) -> str:
        return self.prepared.pose_status()


def estimate_poses_job(settings: PoseSettings, loaded: Optional[Capture] = None) -> JobFunction:
    """A job function that runs SfM on `loaded` (or the capture loaded from settings.capture_path when
    None) and aligns the result to gravity and metres (`engine.poses.prepare`)."""

    def run(progress: ProgressCallback, cancel: CancelToken) -> PosedCapture:
        capture = loaded
        if capture is None:
            capture = engine_capture.load_capture(settings.capture_path, progress=progress, cancel=cancel)
        cancel.check()
        options = engine_poses.SfmOptions(matcher=settings.matcher, features=settings.features,
                                          max_side=settings.max_image_side)
        prepared = prepare_capture(capture, camera_height=settings.camera_height, sfm=SFM_ALWAYS, sfm_options=options,
                                   progress=progress, cancel=cancel)
        return PosedCapture(prepared=prepared, capture_path=settings.capture_path, loaded=capture)

    return run


@dataclass(frozen=True)
class RefinedPoses:
    result: "RefineResult"

    def summary(self) -> str:
        """One line for the report: how many frames moved and by how much (median / max)."""
        r = self.result
        if r.kept_given:
            return f"Kept the given poses: {r.kept_given}"
        return (f"Refined {len(r.refined)} of {len(r.changes)} posed frames: rotation changed by "
                f"{r.rotation_deg_median:.2f} deg median, {r.rotation_deg_max:.2f} deg max; position by "
                f"{_length(r.translation_median, r.units)} median, {_length(r.translation_max, r.units)} max")

    def frame_warnings(self) -> list[str]:
        """One warning per frame that kept its given pose: refused (it moved too far) or not refined
        (none when the refinement as a whole kept the given poses: the summary says why)."""
        if self.result.kept_given:
            return []
        return [f"{change.name} {change.status} ({change.reason}); it keeps its given pose"
                for change in self.result.changes if change.status != STATUS_REFINED]


def _length(value: float, units: str) -> str:
    return f"{100 * value:.1f} cm" if units == "m" else f"{value:.3g} {units}"


def refine_poses_job(capture: Capture, options: Optional["RefineOptions"] = None) -> JobFunction:
    """A job function refining the posed frames of `capture` (rebuilt from the scene's cameras on the
    main thread) against its photos with pycolmap (`engine.poses.refine_poses`, in a subprocess)."""

    def run(progress: ProgressCallback, cancel: CancelToken) -> RefinedPoses:
        return RefinedPoses(engine_poses.refine_poses(capture, options, progress=progress, cancel=cancel))

    return run


def apply_refined_poses(scene: "bpy.types.Scene", refined: "RefineResult") -> None:
    """Move the scene's capture cameras to `refined`'s poses (main thread), add its sparse points when
    the scene has none, and record that the poses were refined (which clears the pose check's warning).
    When the refinement kept the given poses (they were no worse), the cameras stay and the status says so."""
    if not refined.kept_given:
        move_capture_cameras(scene, [f.pose for f in refined.capture.posed_frames])
    if find_point_cloud(scene) is None and len(refined.points):
        apply_point_cloud(scene, *checked_points(refined.points, refined.point_colors))
    settings = scene.vortx
    # The reason with its numbers goes into the status, whose tooltip shows it whole.
    mark = f"kept as given ({refined.kept_given})" if refined.kept_given else "refined"
    if mark not in settings.pose_status:
        settings.pose_status = f"{settings.pose_status}, {mark}"
    settings.pose_source = POSES_KEPT if refined.kept_given else POSES_REFINED
    settings.pose_check = ""
    # What the refinement did and what each stage cost, as the sidecar's poses.refinement: the batch report reads it.
    scene[REFINEMENT_RECORD] = json.dumps(refinement_summary(refined))
    print(refined.report)


REFINEMENT_RECORD = "vortx_pose_refinement"  # scene custom property: the last refinement's summary (JSON)
