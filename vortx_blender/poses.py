"""The Estimate Poses job: structure from motion, gravity and scale, as a bpy-free job function.

The settings are copied out of `scene.vortx` on the main thread (`PoseSettings.from_scene`), because
the worker thread must never read Blender data.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..engine.capture import Capture
from ..engine.jobs import CancelToken, ProgressCallback
from .jobs import JobFunction


@dataclass(frozen=True)
class PoseSettings:
    capture_path: Path
    matcher: str  # "auto" | "sequential" | "exhaustive"
    max_image_side: int
    camera_height: float

    @staticmethod
    def from_scene(settings: object) -> "PoseSettings":
        import bpy

        return PoseSettings(
            capture_path=Path(bpy.path.abspath(settings.capture_path)),
            matcher=settings.sfm_matcher.lower(),
            max_image_side=int(settings.sfm_max_image_side),
            camera_height=float(settings.camera_height),
        )


@dataclass(frozen=True)
class PosedCapture:
    capture: Capture
    capture_path: Path
    report: str

    def pose_status(self) -> str:
        posed, total = len(self.capture.posed_frames), len(self.capture.frames)
        return f"{posed} of {total} posed by SfM"


def estimate_poses_job(settings: PoseSettings) -> JobFunction:
    """A job function that loads the capture, runs SfM and aligns the result to gravity and metres."""

    def run(progress: ProgressCallback, cancel: CancelToken) -> PosedCapture:
        # Imported here: pycolmap and friends load only when the user actually estimates poses.
        from ..engine import poses as engine_poses
        from ..engine.capture import load_capture

        capture = load_capture(settings.capture_path)
        cancel.check()
        options = engine_poses.PoseOptions(matcher=settings.matcher, max_image_size=settings.max_image_side)
        result = engine_poses.estimate_poses(capture, options, progress=progress, cancel=cancel)
        cancel.check()
        aligned = engine_poses.align_gravity_and_scale(result.capture, camera_height=settings.camera_height)
        return PosedCapture(capture=aligned, capture_path=settings.capture_path, report=result.report)

    return run
