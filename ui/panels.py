"""The "VoRTX" tab of the 3D View sidebar (N panel). Drawing only.

Each panel's draw() forwards to a `draw_*(layout, settings, ...)` function so tests can drive the
layout code with a recording stand-in for UILayout (there is no region to draw into headless).
"""

from __future__ import annotations

import textwrap
from typing import Any, Optional

import bpy

from ..engine.texture.options import MOBILE_TEXTURE_SIZE, TextureOptions
from ..vortx_blender import jobs
from ..vortx_blender import result as results
from ..vortx_blender.frame import capture_frame_note
from ..vortx_blender.jobs import Job
from ..vortx_blender.properties import recon_property_names
from ..vortx_blender.texture import bake_summary

CATEGORY = "VoRTX"
# Jobs whose progress the Reconstruction and Result panels show; the Capture panel shows the others.
RECONSTRUCTION_JOBS = ("Reconstruct", "Preview Tiles")
RESULT_JOBS = ("Bake Texture",)
# What the Result panel says about the texture settings: the VR preset's defaults (engine/texture/options.py).
VR_PRESET_TEXT = (f"VR preset: {TextureOptions.face_budget // 1000}k faces, {TextureOptions.texture_size} px "
                  f"({MOBILE_TEXTURE_SIZE} px for mobile headsets)")


# Blender cuts a label that does not fit with "..." in its middle, so long text is wrapped to the
# sidebar's width. Measured in the real window (Blender 4.3, UI scale 1, sidebar 291 px): 36-38
# characters of panel text fit beside an icon inside a box (about 6 px a character and 70 px of tab
# strip, box and icon margins).
CHAR_PX = 6.0
MARGIN_PX = 70
WRAP_CHARS = 36  # the default sidebar's width, and what a draw without a region (tests, scripts) uses
MIN_WRAP_CHARS = 16


def wrap_chars(context: Any) -> int:
    """Characters of panel text that fit on one line of the sidebar `context` draws into."""
    region = getattr(context, "region", None)
    width = getattr(region, "width", 0) or 0
    if width <= MARGIN_PX:  # no region (headless) or collapsed
        return WRAP_CHARS
    scale = bpy.context.preferences.system.ui_scale or 1.0  # the resolution scale times the display's DPI
    return max(MIN_WRAP_CHARS, int((width / scale - MARGIN_PX) / CHAR_PX))


def _value_row(layout: Any, label: str, value: str, chars: int = WRAP_CHARS) -> None:
    # Summary values are written by the operators; showing them as labels (not editable fields)
    # keeps users from typing a frame count that no longer matches the cameras.
    if len(value) > int(0.6 * chars):  # e.g. "36 of 36 posed by SfM, scaled by the ...": whole, under its label
        layout.label(text=f"{label}:")
        for line in textwrap.wrap(value, chars):
            layout.label(text=line, icon="BLANK1")
        return
    row = layout.row()
    split = row.split(factor=0.4)
    split.label(text=label)
    split.label(text=value)


def scale_text(settings: Any) -> str:
    """The scale row: metres or not, what set it, and its uncertainty when it was estimated."""
    units = "metres" if settings.poses_metric else "arbitrary"
    if not settings.scale_source:
        return units
    sigma = f", +-{100 * settings.scale_uncertainty:.0f} %" if settings.scale_uncertainty > 0 else ""
    return f"{units} ({settings.scale_source}{sigma})"


def _wrapped(layout: Any, text: str, icon: str, chars: int = WRAP_CHARS) -> None:
    lines = textwrap.wrap(text, chars) or [""]
    for index, line in enumerate(lines):
        layout.label(text=line, icon=icon if index == 0 else "BLANK1")


def draw_capture(layout: Any, settings: Any, job: Optional[Job], chars: int = WRAP_CHARS) -> None:
    layout.operator("vortx.import_capture", icon="FILE_FOLDER")
    # The coordinates the capture is shown (and the result exported) in: an import option that also
    # moves an imported capture at once. Greyed out, with the reason, when the capture has none of its own.
    row = layout.row()
    row.label(text="Coordinates")
    row.prop(settings, "output_frame", expand=True)
    note = capture_frame_note(settings)
    if note is not None:
        row.enabled = False
        _wrapped(layout, f"No capture coordinates: {note}", "INFO", chars)
    if settings.capture_path:
        box = layout.box()
        col = box.column(align=True)
        col.label(text=bpy.path.basename(settings.capture_path.rstrip("/\\")) or settings.capture_path, icon="IMAGE_DATA")
        _value_row(col, "Format", settings.capture_format, chars)
        _value_row(col, "Frames", str(settings.frame_count), chars)
        _value_row(col, "Resolution", f"{settings.resolution_x} x {settings.resolution_y}", chars)
        _value_row(col, "Poses", settings.pose_status, chars)
        if settings.posed_frame_count:
            _value_row(col, "Scale", scale_text(settings), chars)
            if settings.scale_description:
                # The description is long (floor plane found or not, the numbers): the tooltip-free
                # panel shows it wrapped on its own lines, with a warning icon when it is a guess.
                icon = "ERROR" if settings.scale_source in ("unknown", "") or "no floor" in settings.scale_description else "INFO"
                _wrapped(col, settings.scale_description, icon, chars)
            if settings.pose_check:  # the given poses look off against the photos: Refine Poses below
                _wrapped(col, settings.pose_check, "ERROR", chars)
        if settings.skipped_count:
            _wrapped(col, f"{settings.skipped_count} photo(s) skipped: {settings.skipped_names}", "ERROR", chars)
    else:
        layout.label(text="No capture imported", icon="INFO")
    row = layout.row(align=True)
    row.operator("vortx.estimate_poses", icon="CAMERA_DATA")
    row.operator("vortx.refine_poses", icon="ORIENTATION_GIMBAL")
    layout.operator("vortx.set_scale", icon="DRIVER_DISTANCE")
    if job is not None and job.title not in RECONSTRUCTION_JOBS + RESULT_JOBS:
        layout.progress(text=job.status_text(), factor=job.progress.fraction, type="BAR")


def draw_pose_settings(layout: Any, settings: Any) -> None:
    layout.use_property_split = True
    layout.use_property_decorate = False
    layout.prop(settings, "sfm_matcher")
    layout.prop(settings, "sfm_max_image_side")
    layout.prop(settings, "camera_height")


def _settings_layout(layout: Any) -> None:
    layout.use_property_split = True
    layout.use_property_decorate = False


def draw_reconstruction(layout: Any, settings: Any, job: Optional[Job]) -> None:
    layout.operator("vortx.reconstruct", icon="MOD_REMESH")
    if job is not None and job.title in RECONSTRUCTION_JOBS:
        layout.progress(text=job.status_text(), factor=job.progress.fraction, type="BAR")
    _settings_layout(layout)
    layout.prop(settings, "method")
    layout.prop(settings, "voxel_size")
    if settings.method == "VORTX":  # tiles and views are the network's; stereo fuses the whole scene at once
        layout.prop(settings, "view_count")
        layout.prop(settings, "tile_size")
    layout.prop(settings, "result_mode")


def draw_model_settings(layout: Any, settings: Any) -> None:
    _settings_layout(layout)
    layout.prop(settings, "weights_source")
    if settings.weights_source == "FILE":
        layout.prop(settings, "weights_path")
    layout.prop(settings, "device")
    layout.prop(settings, "seed")


def draw_tiles(layout: Any, settings: Any) -> None:
    _settings_layout(layout)
    layout.prop(settings, "show_tiles")
    row = layout.row(align=True)
    row.operator("vortx.preview_tiles", icon="MESH_GRID")
    row.operator("vortx.bake_tiles", icon="MOD_WIREFRAME")


def draw_result_settings(layout: Any, settings: Any, result: Optional[Any] = None, job: Optional[Job] = None,
                         chars: int = WRAP_CHARS) -> None:
    """`result`: the result object the observation toggle and Bake Texture act on (results.shown_result),
    or None; `job`: the running job (its progress is shown here when it is a bake)."""
    _settings_layout(layout)
    if result is not None:
        if results.has_observation(result.data):
            layout.prop(result, results.SHOW_OBSERVATION, icon="HIDE_OFF")
        else:
            layout.label(text="No observation data on this result", icon="INFO")
    col = layout.column(align=True)
    col.prop(settings, "min_piece_faces")
    col.prop(settings, "min_piece_fraction")
    layout.prop(settings, "target_faces")
    row = layout.row(align=True)
    row.operator("vortx.clean_result", icon="BRUSH_DATA")
    row.operator("vortx.export_result", icon="EXPORT")

    layout.separator()
    col = layout.column(align=True)
    col.prop(settings, "texture_size")
    col.prop(settings, "face_budget")
    _wrapped(layout, VR_PRESET_TEXT, "INFO", chars)
    layout.operator("vortx.bake_texture", icon="TEXTURE")
    if job is not None and job.title in RESULT_JOBS:
        layout.progress(text=job.status_text(), factor=job.progress.fraction, type="BAR")
    baked = bake_summary(result) if result is not None else None
    if baked is not None:
        layout.label(text=f"Textured: {baked['texture_size']} px, {baked['stats'].get('faces', '?')} faces", icon="CHECKMARK")


# Reconstruction settings laid out in the Reconstruction, Model and Result panels (the coordinates in the
# Capture panel); the stereo method's settings (stereo_*) appear in the Stereo panel and every other
# ReconSettings field offered to Blender under Advanced, each by itself in declaration order.
DRAWN_ELSEWHERE = ("method", "voxel_size", "view_count", "tile_size", "device", "seed", "texture_size", "face_budget",
                   "output_frame")
STEREO_PREFIX = "stereo_"


def draw_stereo_settings(layout: Any, settings: Any) -> None:
    _settings_layout(layout)
    for name in recon_property_names():
        if name.startswith(STEREO_PREFIX):
            layout.prop(settings, name)


def draw_advanced_settings(layout: Any, settings: Any) -> None:
    _settings_layout(layout)
    for name in recon_property_names():
        if name not in DRAWN_ELSEWHERE and not name.startswith(STEREO_PREFIX):
            layout.prop(settings, name)


class VORTX_PT_capture(bpy.types.Panel):
    bl_idname = "VORTX_PT_capture"
    bl_label = "Capture"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY

    def draw(self, context: bpy.types.Context) -> None:
        draw_capture(self.layout, context.scene.vortx, jobs.active_job(), wrap_chars(context))


class VORTX_PT_pose_settings(bpy.types.Panel):
    bl_idname = "VORTX_PT_pose_settings"
    bl_label = "Pose Estimation"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY
    bl_parent_id = "VORTX_PT_capture"
    bl_options = {"DEFAULT_CLOSED"}

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


class VORTX_PT_model(_ReconstructionChild):
    bl_idname = "VORTX_PT_model"
    bl_label = "Model"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context: bpy.types.Context) -> None:
        draw_model_settings(self.layout, context.scene.vortx)


class VORTX_PT_stereo(_ReconstructionChild):
    bl_idname = "VORTX_PT_stereo"
    bl_label = "Stereo"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context: bpy.types.Context) -> None:
        draw_stereo_settings(self.layout, context.scene.vortx)


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
                             jobs.active_job(), wrap_chars(context))


class VORTX_PT_advanced(_ReconstructionChild):
    bl_idname = "VORTX_PT_advanced"
    bl_label = "Advanced"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context: bpy.types.Context) -> None:
        draw_advanced_settings(self.layout, context.scene.vortx)


classes = (
    VORTX_PT_capture,
    VORTX_PT_pose_settings,
    VORTX_PT_reconstruction,
    VORTX_PT_model,
    VORTX_PT_stereo,
    VORTX_PT_tiles,
    VORTX_PT_result,
    VORTX_PT_advanced,
)
