"""Capture operators: import a capture, estimate its camera poses. Thin: logic is in vortx_blender."""

# No `from __future__ import annotations`: bpy reads the property annotations as objects.
import bpy
from bpy.props import BoolProperty, StringProperty

from ..engine.errors import CaptureError
from ..vortx_blender.capture import (
    ImportedCapture,
    apply_capture,
    import_capture_job,
    loaded_capture,
    remember_loaded_capture,
    resolve_capture_path,
    scene_camera_height,
)
from ..vortx_blender.job_operator import JobOperatorMixin
from ..vortx_blender.jobs import JobFunction
from ..vortx_blender.poses import PosedCapture, PoseSettings, estimate_poses_job

# Files a capture can be chosen by; a folder is chosen by accepting the browser with no file selected.
CAPTURE_FILE_GLOB = "*.json;*.txt;*.mp4;*.mov;*.m4v;*.avi;*.mkv;*.webm"


def _report_applied(op: bpy.types.Operator, summary: str, warnings: list[str]) -> None:
    for warning in warnings:
        op.report({"WARNING"}, warning)
    op.report({"INFO"}, summary)


class VORTX_OT_import_capture(JobOperatorMixin, bpy.types.Operator):
    """Import photos of a room (a folder, transforms.json, COLMAP or ScanNet layout, or a video) and create cameras for posed photos"""

    bl_idname = "vortx.import_capture"
    bl_label = "Import Capture"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Import Capture"

    filepath: StringProperty(name="File Path", description="Capture folder or file", subtype="FILE_PATH", options={"SKIP_SAVE"})
    directory: StringProperty(subtype="DIR_PATH", options={"SKIP_SAVE", "HIDDEN"})
    filter_glob: StringProperty(default=CAPTURE_FILE_GLOB, options={"HIDDEN"})
    filter_folder: BoolProperty(default=True, options={"HIDDEN"})

    def invoke(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        if not self.filepath and context.scene.vortx.capture_path:
            self.filepath = context.scene.vortx.capture_path
        context.window_manager.fileselect_add(self)  # then Blender calls execute, which goes modal
        return {"RUNNING_MODAL"}

    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        path = resolve_capture_path(self.filepath, self.directory)
        if path is None:
            raise CaptureError("Choose a capture folder or file (transforms.json, a video, ...)")
        self._path = path
        return import_capture_job(path, camera_height=scene_camera_height(context.scene.vortx))

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, result: ImportedCapture) -> set[str]:
        prepared = result.prepared
        applied = apply_capture(scene, prepared.capture, self._path, pose_status=prepared.pose_status())
        remember_loaded_capture(scene, self._path, result.loaded)
        for line in prepared.report_lines:
            print(line)
        _report_applied(self, f"Imported {self._path.name}: {applied.message(prepared.capture)}; {prepared.description}",
                        prepared.warnings + applied.warnings)
        return {"FINISHED"}


class VORTX_OT_estimate_poses(JobOperatorMixin, bpy.types.Operator):
    """Estimate camera poses of the imported capture with structure from motion (Esc cancels), then create its cameras"""

    bl_idname = "vortx.estimate_poses"
    bl_label = "Estimate Poses"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Estimate Poses"

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        if not super().poll(context):
            return False
        if not context.scene.vortx.capture_path:
            cls.poll_message_set("Import a capture first")
            return False
        return True

    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        settings = PoseSettings.from_scene(context.scene.vortx)
        return estimate_poses_job(settings, loaded_capture(context.scene, settings.capture_path))

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, result: PosedCapture) -> set[str]:
        applied = apply_capture(scene, result.capture, result.capture_path, pose_status=result.pose_status())
        remember_loaded_capture(scene, result.capture_path, result.loaded)
        if result.report:
            print(result.report)  # the full SfM report (per-image registration, errors) for the console
        _report_applied(self, f"Estimated poses: {applied.message(result.capture)}", result.warnings + applied.warnings)
        return {"FINISHED"}


classes = (VORTX_OT_import_capture, VORTX_OT_estimate_poses)
