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
    report: str  # the engine's multi-line SfM report, for the console
    warnings: list[str]
    scale_source: str  # "camera height", "known distance", "metric capture", "unknown"

    def pose_status(self) -> str:
        posed, total = len(self.capture.posed_frames), len(self.capture.frames)
        scale = {
            "camera height": "scaled by camera height",
            "known distance": "scaled by a known distance",
            "metric capture": "metric",
        }
        return f"{posed} of {total} posed by SfM, " + scale.get(self.scale_source, "scale unknown")


def estimate_poses_job(settings: PoseSettings) -> JobFunction:
    """A job function that loads the capture, runs SfM and aligns the result to gravity and metres."""

    def run(progress: ProgressCallback, cancel: CancelToken) -> PosedCapture:
        # Imported here: the SfM code loads only when the user actually estimates poses.
        from ..engine import capture as engine_capture
        from ..engine import poses as engine_poses

        capture = engine_capture.load_capture(settings.capture_path, progress=progress, cancel=cancel)
        cancel.check()
        # align=True: the engine applies align_gravity_and_scale to the SfM model itself, where it
        # also has the sparse points that locate the floor (the scale comes from the camera height).
        options = engine_poses.SfmOptions(
            matcher=settings.matcher,
            max_side=settings.max_image_side,
            align=True,
            camera_height=settings.camera_height,
        )
        result = engine_poses.estimate_poses(capture, options, progress=progress, cancel=cancel)
        return PosedCapture(
            capture=result.capture,
            capture_path=settings.capture_path,
            report=result.report,
            warnings=list(result.warnings),
            scale_source=result.alignment.scale_source if result.alignment is not None else "unknown",
        )

    return run
