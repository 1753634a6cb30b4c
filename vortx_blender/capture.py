"""Putting a Capture into a scene: the capture summary on `scene.vortx`, one camera per posed frame and
the sparse points (`point_cloud.py`) when the capture has them.

Both operators (import, estimate poses) end here. Everything that can fail (the engine, validating
intrinsics and poses) happens before the first write, so a failure leaves the scene unchanged.

Import prepares the capture exactly as `python -m engine reconstruct` does (`engine.poses.prepare`:
Z up, scaled from the camera height), so the cameras stand in the world the network reconstructs in.
The capture as loaded is kept in memory per scene, so Estimate Poses does not load it (check photos,
extract video frames) a second time.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import bpy

from ..engine import capture as engine_capture
from ..engine.capture import Capture
from ..engine.jobs import CancelToken, ProgressCallback
from ..engine.poses.prepare import SFM_NEVER, PreparedCapture, prepare_capture
from ..engine.recon.output_frame import FRAME_CAPTURE, FRAME_WORLD, NO_POSES_NO_CAPTURE_FRAME, frame_record
from .cameras import apply_camera_plan, plan_capture_cameras
from .frame import unavailable
from .jobs import JobFunction
from .point_cloud import apply_point_cloud, checked_points
from .properties import POSES_BY_SFM, POSES_GIVEN, capture_summary, write_summary


@dataclass
class CaptureApplied:
    cameras: list["bpy.types.Object"]
    warnings: list[str] = field(default_factory=list)

    def message(self, capture: Capture) -> str:
        posed = len(capture.posed_frames)
        return f"{len(capture.frames)} frames ({capture.format}), {posed} posed, {len(self.cameras)} cameras"


def resolve_capture_path(filepath: str, directory: str = "") -> Optional[Path]:
    """The folder or file the user chose in the file browser.

    Blender's browser returns `filepath` = folder + "" when the user accepts a folder without
    picking a file, and may leave `filepath` empty and set only `directory` when called from scripts.
    Relative paths ("//photos") are relative to the .blend file.
    """
    for candidate in (filepath, directory):
        if not candidate:
            continue
        path = Path(bpy.path.abspath(candidate))
        if path.is_file() or path.is_dir():
            return path
    chosen = filepath or directory
    return Path(bpy.path.abspath(chosen)) if chosen else None


def apply_capture(scene: "bpy.types.Scene", capture: Capture, path: os.PathLike | str, pose_status: Optional[str] = None,
                  scale_source: str = "", scale_description: str = "", scale_uncertainty: float = 0.0,
                  pose_check: str = "", pose_source: str = POSES_GIVEN) -> CaptureApplied:
    """Replace the scene's capture summary, capture cameras and sparse points with `capture`'s.

    Raises CaptureError / PoseError (from validation) before changing anything.
    """
    summary = capture_summary(capture, str(path), pose_status, scale_source, scale_description, scale_uncertainty,
                              pose_check, pose_source)
    plan = plan_capture_cameras(capture)
    points, colours = checked_points(capture.points, capture.point_colors)
    cameras = apply_camera_plan(scene, plan)
    apply_point_cloud(scene, points, colours)
    write_summary(scene.vortx, summary)
    return CaptureApplied(cameras=cameras, warnings=list(capture.warnings) + plan.warnings)


def apply_prepared(scene: "bpy.types.Scene", prepared: PreparedCapture, path: os.PathLike | str) -> CaptureApplied:
    """`apply_capture` for a prepared capture: its pose status, where its scale came from, and its
    sparse points (SfM's, the refinement's or the capture's own, moved to the prepared world)."""
    capture = prepared.capture.with_points(prepared.points, prepared.point_colors)
    return apply_capture(scene, capture, path, pose_status=prepared.pose_status(),
                         scale_source=prepared.scale_source, scale_description=prepared.description,
                         scale_uncertainty=prepared.scale.relative_sigma if prepared.scale is not None else 0.0,
                         pose_check=prepared.pose_check.message if prepared.pose_check is not None
                         and prepared.pose_check.poses_off else "",
                         pose_source=POSES_BY_SFM if prepared.ran_sfm else (capture.pose_origin or POSES_GIVEN))


def scene_camera_height(settings: object) -> float:
    """scene.vortx.camera_height in metres as the user typed it: the property is float32 (1.7 reads as
    1.70000005), rounded so the panel, the CLI and the batch script give the same world."""
    return round(float(settings.camera_height), 6)


def record_capture_frame(scene: "bpy.types.Scene", prepared: PreparedCapture) -> None:
    """scene.vortx.capture_frame: the similarity between the capture's own coordinates and the world its
    cameras were just placed in (`frame_record`, as `engine reconstruct`'s sidecar has it), so the batch
    report and scripts can map the result back over the capture's cameras. Recorded for the world here;
    `frame.show_frame` then records (and shows) the coordinates scene.vortx.output_frame asks for."""
    scene.vortx.capture_frame = json.dumps(frame_record(prepared, FRAME_WORLD))


@dataclass(frozen=True)
class ImportedCapture:
    loaded: Capture  # as the loader returned it (kept for Estimate Poses)
    prepared: PreparedCapture  # Z up and scaled: what the scene's cameras show


def import_capture_job(path: Path, camera_height: float, frame: str = FRAME_WORLD) -> JobFunction:
    """A job function loading the capture at `path` (photo checks, video frames, undistortion can
    take minutes, hence a job rather than a plain call) and preparing its posed frames (never SfM:
    that is the Estimate Poses button). frame: the coordinates it is to be shown in; FRAME_CAPTURE for
    photos without poses is refused as soon as they are loaded."""

    def run(progress: ProgressCallback, cancel: CancelToken) -> ImportedCapture:
        loaded = engine_capture.load_capture(path, progress=progress, cancel=cancel)
        cancel.check()
        if frame == FRAME_CAPTURE and not loaded.posed_frames:  # before the pose check spends seconds
            raise unavailable(NO_POSES_NO_CAPTURE_FRAME)
        # Given poses are checked against the photos here (seconds), so the panel can say when they look off.
        return ImportedCapture(loaded, prepare_capture(loaded, camera_height=camera_height, sfm=SFM_NEVER,
                                                       progress=progress, cancel=cancel, check_poses=True))

    return run


# scene.session_uid -> (capture path, the capture as loaded). Python objects cannot live in Blender
# data, and a reopened .blend has no entry: Estimate Poses then loads the capture from disk.
_loaded_captures: dict[int, tuple[Path, Capture]] = {}


def remember_loaded_capture(scene: "bpy.types.Scene", path: Path, capture: Capture) -> None:
    _loaded_captures[scene.session_uid] = (Path(path), capture)


def loaded_capture(scene: "bpy.types.Scene", path: Path) -> Optional[Capture]:
    """The capture this scene imported from `path` in this session, or None."""
    entry = _loaded_captures.get(scene.session_uid)
    return entry[1] if entry is not None and entry[0] == Path(path) else None
