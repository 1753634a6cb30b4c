"""Capture operators: import a capture, estimate or refine its camera poses, set its scale. Thin: logic
is in vortx_blender."""

# No `from __future__ import annotations`: bpy reads the property annotations as objects.
import bpy
from bpy.props import BoolProperty, FloatProperty, StringProperty

from ..engine.errors import CaptureError, PoseError, VortxError
from ..engine.recon.output_frame import SFM_HAS_NO_CAPTURE_FRAME, capture_frame_missing
from ..vortx_blender import frame as frames
from ..vortx_blender.cameras import move_capture_cameras, posed_capture_from_scene
from ..vortx_blender.capture import (
    ImportedCapture,
    apply_prepared,
    import_capture_job,
    loaded_capture,
    record_capture_frame,
    remember_loaded_capture,
    resolve_capture_path,
    scene_camera_height,
)
from ..vortx_blender.job_operator import JobOperatorMixin
from ..vortx_blender.jobs import JobFunction
from ..vortx_blender.point_cloud import apply_point_cloud, checked_points, find_point_cloud
from ..vortx_blender.poses import (
    PosedCapture,
    PoseSettings,
    RefinedPoses,
    apply_refined_poses,
    estimate_poses_job,
    refine_poses_job,
)
from ..vortx_blender.properties import POSES_REFINED, recon_field, recon_property
from ..vortx_blender.scale import picked_points, set_scale

# Files a capture can be chosen by; a folder is chosen by accepting the browser with no file selected.
CAPTURE_FILE_GLOB = "*.json;*.txt;*.mp4;*.mov;*.m4v;*.avi;*.mkv;*.webm;*.zip;*.r3d"


def _report_applied(op: bpy.types.Operator, summary: str, warnings: list[str]) -> None:
    for warning in warnings:
        op.report({"WARNING"}, warning)
    op.report({"INFO"}, summary)


class VORTX_OT_import_capture(JobOperatorMixin, bpy.types.Operator):
    """Import photos of a room (a folder, transforms.json, COLMAP or ScanNet layout, a video, or a phone app's export or its zip) and create cameras for posed photos"""

    bl_idname = "vortx.import_capture"
    bl_label = "Import Capture"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Import Capture"

    filepath: StringProperty(name="File Path", description="Capture folder or file", subtype="FILE_PATH", options={"SKIP_SAVE"})
    directory: StringProperty(subtype="DIR_PATH", options={"SKIP_SAVE", "HIDDEN"})
    filter_glob: StringProperty(default=CAPTURE_FILE_GLOB, options={"HIDDEN"})
    filter_folder: BoolProperty(default=True, options={"HIDDEN"})
    # The scene's Coordinates setting (ReconSettings.frame), offered in the file browser too; when a
    # script leaves it out, the scene's setting holds.
    output_frame: recon_property(recon_field("frame"), options={"SKIP_SAVE"})

    def invoke(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        if not self.filepath and context.scene.vortx.capture_path:
            self.filepath = context.scene.vortx.capture_path
        if not self.properties.is_property_set("output_frame"):
            self.output_frame = context.scene.vortx.output_frame
        context.window_manager.fileselect_add(self)  # then Blender calls execute, which goes modal
        return {"RUNNING_MODAL"}

    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        path = resolve_capture_path(self.filepath, self.directory)
        if path is None:
            raise CaptureError("Choose a capture folder or file (transforms.json, a video, a phone app's .zip, ...)")
        self._path = path
        settings = context.scene.vortx
        self._frame = self.output_frame if self.properties.is_property_set("output_frame") else settings.output_frame
        return import_capture_job(path, camera_height=scene_camera_height(settings), frame=self._frame.lower())

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, result: ImportedCapture) -> set[str]:
        prepared = result.prepared
        missing = capture_frame_missing(prepared)
        if self._frame == frames.CAPTURE and missing is not None:
            raise frames.unavailable(missing)  # before anything changes
        applied = apply_prepared(scene, prepared, self._path)
        record_capture_frame(scene, prepared)
        scene.vortx.output_frame = self._frame
        frames.show_frame(scene)  # the cameras and points into the chosen coordinates (also when unchanged)
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
        if context.scene.vortx.output_frame == frames.CAPTURE:
            cls.poll_message_set(_SFM_KEEPS_NO_CAPTURE_FRAME)
            return False
        return True

    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        settings = PoseSettings.from_scene(context.scene.vortx)
        return estimate_poses_job(settings, loaded_capture(context.scene, settings.capture_path))

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, result: PosedCapture) -> set[str]:
        if scene.vortx.output_frame == frames.CAPTURE:  # chosen while structure from motion ran
            raise VortxError(_SFM_KEEPS_NO_CAPTURE_FRAME + "; nothing was changed")
        applied = apply_prepared(scene, result.prepared, result.capture_path)
        record_capture_frame(scene, result.prepared)  # none of its own: SfM made the poses
        frames.show_frame(scene)
        remember_loaded_capture(scene, result.capture_path, result.loaded)
        if result.report:
            print(result.report)  # the full SfM report (per-image registration, errors) for the console
        # The scale's derivation, which the Capture panel shortens to one line, goes into the report.
        _report_applied(self, f"Estimated poses: {applied.message(result.capture)}; {result.prepared.description}",
                        result.warnings + applied.warnings)
        return {"FINISHED"}


# Why Estimate Poses cannot run while the scene shows the capture's own coordinates.
_SFM_KEEPS_NO_CAPTURE_FRAME = (f"Coordinates is set to Capture, which Estimate Poses cannot keep: {SFM_HAS_NO_CAPTURE_FRAME}. "
                               "Set Coordinates to World (Capture panel) first")


def _has_capture_cameras(cls: type, context: bpy.types.Context) -> bool:
    if not context.scene.vortx.posed_frame_count:
        cls.poll_message_set("Import a capture with poses or run Estimate Poses first")
        return False
    return True


class VORTX_OT_refine_poses(JobOperatorMixin, bpy.types.Operator):
    """Refine the capture cameras' poses against the photos (given poses from trackers and apps are often a little off); Esc cancels"""

    bl_idname = "vortx.refine_poses"
    bl_label = "Refine Poses"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Refine Poses"

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        return super().poll(context) and _has_capture_cameras(cls, context)

    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        capture = posed_capture_from_scene(context.scene)
        if capture is None or not capture.posed_frames:
            raise PoseError("Refine Poses needs the capture's cameras: import a capture with poses first")
        return refine_poses_job(capture)

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, result: RefinedPoses) -> set[str]:
        refined = result.result
        apply_refined_poses(scene, refined)
        _report_applied(self, result.summary(), result.frame_warnings() + list(refined.warnings))
        return {"FINISHED"}


class VORTX_OT_set_scale(bpy.types.Operator):
    """Scale the capture (cameras, sparse points) and any result so that two picked points are a known distance apart: select two capture cameras (Object Mode) or two vertices of the result or the sparse points (Edit Mode)"""

    bl_idname = "vortx.set_scale"
    bl_label = "Set Scale"
    bl_options = {"REGISTER", "UNDO"}

    distance: FloatProperty(name="Distance", description="The real distance between the two picked points",
                            default=1.0, subtype="DISTANCE", unit="LENGTH", soft_min=0.01, step=1, precision=3)

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        return context.scene is not None and _has_capture_cameras(cls, context)

    def invoke(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context: bpy.types.Context) -> set[str]:
        try:
            change = set_scale(context.scene, picked_points(context), float(self.distance))
        except PoseError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        self.report({"INFO"}, change.description)
        return {"FINISHED"}


classes = (VORTX_OT_import_capture, VORTX_OT_estimate_poses, VORTX_OT_refine_poses, VORTX_OT_set_scale)
