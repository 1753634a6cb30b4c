"""Putting a Capture into a scene: the capture summary on `scene.vortx` plus one camera per posed frame.

Both operators (import, estimate poses) end here. Everything that can fail (the engine, validating
intrinsics and poses) happens before the first write, so a failure leaves the scene unchanged.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Optional

from ..engine import capture as engine_capture
from ..engine.capture import Capture
from ..engine.jobs import CancelToken, ProgressCallback
from .cameras import apply_camera_plan, plan_capture_cameras
from .jobs import JobFunction
from .properties import capture_summary, write_summary

if TYPE_CHECKING:
    import bpy


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
    import bpy

    for candidate in (filepath, directory):
        if not candidate:
            continue
        path = Path(bpy.path.abspath(candidate))
        if path.is_file() or path.is_dir():
            return path
    chosen = filepath or directory
    return Path(bpy.path.abspath(chosen)) if chosen else None


def apply_capture(scene: "bpy.types.Scene", capture: Capture, path: os.PathLike | str, pose_status: Optional[str] = None) -> CaptureApplied:
    """Replace the scene's capture summary and capture cameras with `capture`'s.

    Raises CaptureError / PoseError (from validation) before changing anything.
    """
    summary = capture_summary(capture, str(path), pose_status)
    plan = plan_capture_cameras(capture)
    cameras = apply_camera_plan(scene, plan)
    write_summary(scene.vortx, summary)
    return CaptureApplied(cameras=cameras, warnings=list(capture.warnings) + plan.warnings)


def import_capture_job(path: Path) -> JobFunction:
    """A job function loading the capture at `path` (photo checks, video frames, undistortion can
    take minutes, hence a job rather than a plain call)."""

    def run(progress: ProgressCallback, cancel: CancelToken) -> Capture:
        return engine_capture.load_capture(path, progress=progress, cancel=cancel)

    return run
