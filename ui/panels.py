"""The "VoRTX" tab of the 3D View sidebar (N panel). Drawing only.

Laid out as Blender's own panels: settings in `use_property_split` columns under short labels (the
property's description is the tooltip); status as one line each, a warning as one line with an icon
whose whole text is its tooltip (the `vortx.explain` operator drawn as a label) and the operator's
report; details and raw knobs in sub-panels closed by default. Every text fits the default sidebar
(ui/sidebar.py has the measured widths; tests/ui/test_label_widths.py checks each panel).

Each panel's draw() forwards to a `draw_*(layout, settings, ...)` function so tests can drive the
layout code with a recording stand-in for UILayout (there is no region to draw into headless).
"""

from __future__ import annotations

from typing import Any, Optional

import bpy

from ..engine.poses.scale import SOURCE_FLOOR, SOURCE_FLOOR_AND_CEILING, SOURCE_GUESS
from ..engine.recon.presets import preset
from ..engine.recon.settings import BLENDER, setting_fields
from ..vortx_blender import jobs
from ..vortx_blender import result as results
from ..vortx_blender.frame import capture_frame_note
from ..vortx_blender.jobs import Job
from ..vortx_blender.properties import CUSTOM_QUALITY, POSES_BY_SFM, blender_name, recon_property_names
from ..vortx_blender.texture import bake_summary, headset_budget_text
from . import sidebar

CATEGORY = "VoRTX"
# Jobs whose progress the Reconstruction and Result panels show; the Capture panel shows the others.
RECONSTRUCTION_JOBS = ("Reconstruct", "Preview Tiles")
RESULT_JOBS = ("Bake Texture",)

# The Scale line's words for where the scale came from (scene.vortx.scale_source).
SCALE_WORDS = {
    SOURCE_FLOOR: "from the floor",
    SOURCE_FLOOR_AND_CEILING: "floor and ceiling",
    "camera height": "camera height",
    "known distance": "known distance",
    "metric capture": "from the capture",
}
SET_SCALE_ADVICE = "Select two cameras or points a known distance apart and use Set Scale"


def status_line(layout: Any, text: str, icon: str = "NONE", tooltip: str = "", warning: bool = False) -> None:
    """One status line: a label, or, when it stands for a longer text, the `vortx.explain` operator drawn
    as a label (hovering shows `tooltip`, clicking reports it)."""
    if not tooltip:
        layout.label(text=text, icon=icon)
        return
    row = layout.row()
    row.alignment = "LEFT"
    explain = row.operator("vortx.explain", text=text, icon=icon, emboss=False)
    explain.text = tooltip
    explain.level = "WARNING" if warning else "INFO"


def paragraph(layout: Any, text: str, width_px: float, icon: str = "NONE") -> None:
    """`text` wrapped to a panel `width_px` wide (Blender's text width), `icon` before its first line."""
    for index, line in enumerate(sidebar.wrap(text, sidebar.line_px(width_px, icon=icon != "NONE"))):
        layout.label(text=line, icon=icon if index == 0 else ("BLANK1" if icon != "NONE" else "NONE"))


def progress_bar(layout: Any, job: Job, width_px: float = sidebar.CONTENT_PX) -> None:
    """The job's progress bar: its stage, counts and detail, without the detail when that does not fit
    (the status bar and the viewport's tiles have it), shortened only when even the stage does not."""
    room = width_px - sidebar.BUTTON_PAD_PX
    text = job.panel_text()
    if sidebar.text_width(text) > room:
        text = sidebar.shorten(job.panel_text(detail=False), room)
    layout.progress(text=text, factor=job.progress.fraction, type="BAR")


def poses_line(settings: Any) -> str:
    """"Poses: 36 of 36, by SfM"; "Poses: none (Estimate Poses)"."""
    if not settings.posed_frame_count:
        return "Poses: none (Estimate Poses)"
    source = settings.pose_source or "given"
    return f"Poses: {settings.posed_frame_count} of {settings.frame_count}, {'by SfM' if source == POSES_BY_SFM else source}"


def scale_line(settings: Any) -> tuple[str, bool]:
    """The Scale line ("Scale: metric, +-12 %, from the floor") and whether it is a warning (a guess)."""
    source = settings.scale_source
    if source == SOURCE_GUESS:
        return "Scale: guessed, no floor seen", True
    if source in ("unknown", ""):
        return "Scale: unknown", True
    parts = ["metric" if settings.poses_metric else "not metric"]
    if settings.scale_uncertainty > 0:
        parts.append(f"+-{100 * settings.scale_uncertainty:.0f} %")
    parts.append(SCALE_WORDS.get(source, source))
    return "Scale: " + ", ".join(parts), False


def draw_capture(layout: Any, settings: Any, job: Optional[Job], width_px: float = sidebar.CONTENT_PX) -> None:
    layout.operator("vortx.import_capture", icon="FILE_FOLDER")
    # The coordinates the capture is shown (and the result exported) in: an import option that also
    # moves an imported capture at once. Greyed out when the capture has none of its own (the line
    # under it says so, its tooltip why).
    column = layout.column()
    column.use_property_split = True
    column.use_property_decorate = False
    row = column.row()
    row.prop(settings, "output_frame", expand=True)
    note = capture_frame_note(settings)
    if note is not None:
        row.enabled = False
        status_line(layout, "No capture coordinates", "INFO", f"No capture coordinates: {note}")
    if settings.capture_path:
        box = layout.box()
        col = box.column(align=True)
        # Every line of the box is a status line with a tooltip, so they all line up.
        name = bpy.path.basename(settings.capture_path.rstrip("/\\")) or settings.capture_path
        status_line(col, sidebar.shorten(name, sidebar.line_px(width_px, icon=True, boxed=True)), "IMAGE_DATA",
                    settings.capture_path)
        status_line(col, f"Frames: {settings.frame_count}, {settings.resolution_x} x {settings.resolution_y}",
                    tooltip=f"{settings.frame_count} photos of {settings.resolution_x} x {settings.resolution_y} px "
                            f"({settings.capture_format})")
        status_line(col, poses_line(settings), tooltip=settings.pose_status)
        if settings.posed_frame_count:
            text, guessed = scale_line(settings)
            tooltip = ". ".join(t for t in (settings.scale_description, SET_SCALE_ADVICE if guessed else "") if t)
            status_line(col, text, "ERROR" if guessed else "NONE", tooltip, warning=guessed)
            if settings.pose_check:  # the given poses look off against the photos: Refine Poses below
                status_line(col, "Poses look off: Refine Poses", "ERROR", settings.pose_check, warning=True)
        if settings.skipped_count:
            status_line(col, f"{settings.skipped_count} photo{'s' if settings.skipped_count > 1 else ''} skipped", "ERROR",
                        f"Skipped: {settings.skipped_names} (the import report says why)", warning=True)
    else:
        layout.label(text="No capture imported", icon="INFO")
    row = layout.row(align=True)
    row.operator("vortx.estimate_poses", icon="CAMERA_DATA")
    row.operator("vortx.refine_poses", icon="ORIENTATION_GIMBAL")
    layout.operator("vortx.set_scale", icon="DRIVER_DISTANCE")
    if job is not None and job.title not in RECONSTRUCTION_JOBS + RESULT_JOBS:
        progress_bar(layout, job)


def draw_capture_details(layout: Any, settings: Any, width_px: float = sidebar.CONTENT_PX) -> None:
    """The Capture panel's lines in full: format, where the poses come from, how the scale was found,
    the pose check, the skipped photos, why there are no capture coordinates."""
    col = layout.column(align=True)
    col.label(text=f"Format: {settings.capture_format}")
    col.label(text=f"Resolution: {settings.resolution_x} x {settings.resolution_y}")
    paragraph(col, f"Poses: {settings.pose_status}", width_px)
    if settings.posed_frame_count and settings.scale_description:
        _, guessed = scale_line(settings)
        paragraph(col, f"Scale: {settings.scale_description}", width_px, "ERROR" if guessed else "NONE")
    if settings.pose_check:
        paragraph(col, settings.pose_check, width_px, "ERROR")
    if settings.skipped_count:
        paragraph(col, f"{settings.skipped_count} skipped: {settings.skipped_names}", width_px, "ERROR")
    note = capture_frame_note(settings)
    if note is not None:
        paragraph(col, f"No capture coordinates: {note}", width_px, "INFO")


def _settings_layout(layout: Any) -> None:
    layout.use_property_split = True
    layout.use_property_decorate = False


def draw_pose_settings(layout: Any, settings: Any) -> None:
    _settings_layout(layout)
    layout.prop(settings, "sfm_features")
    layout.prop(settings, "sfm_matcher")
    layout.prop(settings, "sfm_max_image_side")
    layout.prop(settings, "camera_height")


def quality_hint(settings: Any) -> Optional[str]:
    """The line under Quality: the chosen preset's measured time on the demo room (None for Custom)."""
    if settings.quality == CUSTOM_QUALITY:
        return None
    chosen = preset(settings.quality.lower())
    return f"Demo room: {chosen.time_text()}" if chosen.demo_seconds is not None else "Not measured yet"


def draw_reconstruction(layout: Any, settings: Any, job: Optional[Job]) -> None:
    layout.operator("vortx.reconstruct", icon="MOD_REMESH")
    if settings.pose_check:  # Reconstruct refines poses that look off first, unless this is on (its tooltip says so)
        layout.prop(settings, "keep_given_poses")
    if job is not None and job.title in RECONSTRUCTION_JOBS:
        progress_bar(layout, job)
    _settings_layout(layout)
    layout.prop(settings, "method")
    col = layout.column()
    col.active = settings.method == "STEREO"  # the presets set the stereo settings
    col.prop(settings, "quality")
    hint = quality_hint(settings)
    if hint is not None:
        split = col.split(factor=sidebar.SPLIT_FACTOR)
        split.label(text="")
        split.label(text=hint, icon="TIME")
    layout.prop(settings, "voxel_size")
    layout.prop(settings, "result_mode")


# The VoRTX network's settings: the Model panel.
MODEL_SETTINGS = ("view_count", "tile_size", "image_size")


def draw_model_settings(layout: Any, settings: Any) -> None:
    _settings_layout(layout)
    layout.prop(settings, "weights_source")
    if settings.weights_source == "FILE":
        layout.prop(settings, "weights_path")
    layout.prop(settings, "device")
    layout.prop(settings, "seed")
    for name in MODEL_SETTINGS:
        layout.prop(settings, name)


def draw_tiles(layout: Any, settings: Any) -> None:
    _settings_layout(layout)
    layout.prop(settings, "show_tiles")
    row = layout.row(align=True)
    row.operator("vortx.preview_tiles", icon="MESH_GRID")
    row.operator("vortx.bake_tiles", icon="MOD_WIREFRAME")


def draw_result_settings(layout: Any, settings: Any, result: Optional[Any] = None, job: Optional[Job] = None,
                         width_px: float = sidebar.CONTENT_PX) -> None:
    """`result`: the result object the observation toggle and Bake Texture act on (results.shown_result),
    or None; `job`: the running job (its progress is shown here when it is a bake)."""
    _settings_layout(layout)
    if result is not None:
        if results.has_observation(result.data):
            layout.prop(result, results.SHOW_OBSERVATION)
        else:
            layout.label(text="No observation layer", icon="INFO")
    # How the next reconstruction finishes its mesh (engine/finish): the room's structure, before any clean-up below.
    layout.prop(settings, "finish")
    col = layout.column(align=True)
    for name in ("min_piece_faces", "min_piece_fraction"):
        limit_prop(col, settings, name)
    limit_prop(layout, settings, "target_faces")
    row = layout.row(align=True)
    row.operator("vortx.clean_result", icon="BRUSH_DATA")
    row.operator("vortx.export_result", icon="EXPORT")

    layout.separator()
    col = layout.column(align=True)
    for name in textured_property_names():  # texture size, face budget, ...: what Bake Texture reads
        col.prop(settings, name)
    # The Headset preset's budget (issue 28), wrapped whole: a standalone headset's line is two lines long.
    paragraph(layout.column(align=True), headset_budget_text(settings.id_data), width_px, "INFO")
    layout.operator("vortx.bake_texture", icon="TEXTURE")
    if job is not None and job.title in RESULT_JOBS:
        progress_bar(layout, job)
    baked = bake_summary(result) if result is not None else None
    if baked is not None:
        layout.label(text=f"Textured: {baked['texture_size']} px, {baked['stats'].get('faces', '?')} faces", icon="CHECKMARK")


def limit_prop(layout: Any, settings: Any, name: str) -> None:
    """A clean-up limit whose 0 turns it off: the field, and "Off" beside it while it does nothing
    (Blender cannot show a number field's 0 as a word)."""
    if getattr(settings, name):
        layout.prop(settings, name)
        return
    # The label column as use_property_split draws it, then the field and the word.
    split = layout.split(factor=sidebar.SPLIT_FACTOR)
    label = split.row()
    label.alignment = "RIGHT"
    label.label(text=settings.bl_rna.properties[name].name)
    row = split.row(align=True)
    row.prop(settings, name, text="")
    row.label(text="Off")


def textured_property_names() -> list[str]:
    """The scene properties of the settings only a textured result reads (setting(textured=True)), in
    declaration order: the Result panel's, beside Bake Texture."""
    return [blender_name(f) for f in setting_fields(BLENDER) if f.metadata["textured"]]


# Reconstruction settings laid out in the Reconstruction, Model and Result panels (the coordinates in the
# Capture panel, the textured result's beside Bake Texture); the stereo method's settings (stereo_*)
# appear in Advanced > Stereo and every other ReconSettings field offered to Blender in Advanced, each by
# itself in declaration order.
DRAWN_ELSEWHERE = ("method", "voxel_size", *MODEL_SETTINGS, "device", "seed", "output_frame", "finish")
STEREO_PREFIX = "stereo_"


def draw_stereo_settings(layout: Any, settings: Any) -> None:
    _settings_layout(layout)
    for name in recon_property_names():
        if name.startswith(STEREO_PREFIX):
            layout.prop(settings, name)


def draw_advanced_settings(layout: Any, settings: Any) -> None:
    _settings_layout(layout)
    for name in recon_property_names():
        if name not in DRAWN_ELSEWHERE and not name.startswith(STEREO_PREFIX) and name not in textured_property_names():
            layout.prop(settings, name)


class VORTX_PT_capture(bpy.types.Panel):
    bl_idname = "VORTX_PT_capture"
    bl_label = "Capture"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY

    def draw(self, context: bpy.types.Context) -> None:
        draw_capture(self.layout, context.scene.vortx, jobs.active_job(), sidebar.content_px(context))


class _CaptureChild(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY
    bl_parent_id = "VORTX_PT_capture"
    bl_options = {"DEFAULT_CLOSED"}


class VORTX_PT_capture_details(_CaptureChild):
    bl_idname = "VORTX_PT_capture_details"
    bl_label = "Details"

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        return bool(context.scene.vortx.capture_path)

    def draw(self, context: bpy.types.Context) -> None:
        draw_capture_details(self.layout, context.scene.vortx, sidebar.content_px(context))


class VORTX_PT_pose_settings(_CaptureChild):
    bl_idname = "VORTX_PT_pose_settings"
    bl_label = "Pose Estimation"

    def draw(self, context: bpy.types.Context) -> None:
        draw_pose_settings(self.layout, context.scene.vortx)


class VORTX_PT_reconstruction(bpy.types.Panel):
    bl_idname = "VORTX_PT_reconstruction"
    bl_label = "Reconstruction"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY

    def draw(self, context: bpy.types.Context) -> None:
        draw_reconstruction(self.layout, context.scene.vortx, jobs.active_job())


class _ReconstructionChild(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY
    bl_parent_id = "VORTX_PT_reconstruction"


class VORTX_PT_tiles(_ReconstructionChild):
    bl_idname = "VORTX_PT_tiles"
    bl_label = "Tiles"

    def draw(self, context: bpy.types.Context) -> None:
        draw_tiles(self.layout, context.scene.vortx)


class VORTX_PT_result(_ReconstructionChild):
    bl_idname = "VORTX_PT_result"
    bl_label = "Result"

    def draw(self, context: bpy.types.Context) -> None:
        draw_result_settings(self.layout, context.scene.vortx, results.shown_result(context.scene, context.active_object),
                             jobs.active_job(), sidebar.content_px(context))


class VORTX_PT_model(_ReconstructionChild):
    bl_idname = "VORTX_PT_model"
    bl_label = "Model"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context: bpy.types.Context) -> None:
        draw_model_settings(self.layout, context.scene.vortx)


class VORTX_PT_advanced(_ReconstructionChild):
    """The raw knobs under the Quality presets: closed by default."""

    bl_idname = "VORTX_PT_advanced"
    bl_label = "Advanced"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context: bpy.types.Context) -> None:
        draw_advanced_settings(self.layout, context.scene.vortx)


class VORTX_PT_stereo(_ReconstructionChild):
    bl_idname = "VORTX_PT_stereo"
    bl_label = "Stereo"
    bl_parent_id = "VORTX_PT_advanced"

    def draw(self, context: bpy.types.Context) -> None:
        draw_stereo_settings(self.layout, context.scene.vortx)


# Registration order is the drawing order of sibling panels.
classes = (
    VORTX_PT_capture,
    VORTX_PT_capture_details,
    VORTX_PT_pose_settings,
    VORTX_PT_reconstruction,
    VORTX_PT_tiles,
    VORTX_PT_result,
    VORTX_PT_model,
    VORTX_PT_advanced,
    VORTX_PT_stereo,
)
