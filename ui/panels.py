"""The "VoRTX" tab of the 3D View sidebar (N panel). Drawing only.

Each panel's draw() forwards to a `draw_*(layout, settings, ...)` function so tests can drive the
layout code with a recording stand-in for UILayout (there is no region to draw into headless).
"""

from __future__ import annotations

from typing import Any, Optional

import bpy

from ..vortx_blender import jobs
from ..vortx_blender.jobs import Job

CATEGORY = "VoRTX"


def _value_row(layout: Any, label: str, value: str) -> None:
    # Summary values are written by the operators; showing them as labels (not editable fields)
    # keeps users from typing a frame count that no longer matches the cameras.
    row = layout.row()
    split = row.split(factor=0.4)
    split.label(text=label)
    split.label(text=value)


def draw_capture(layout: Any, settings: Any, job: Optional[Job]) -> None:
    layout.operator("vortx.import_capture", icon="FILE_FOLDER")
    if settings.capture_path:
        box = layout.box()
        col = box.column(align=True)
        col.label(text=bpy.path.basename(settings.capture_path.rstrip("/\\")) or settings.capture_path, icon="IMAGE_DATA")
        _value_row(col, "Format", settings.capture_format)
        _value_row(col, "Frames", str(settings.frame_count))
        _value_row(col, "Resolution", f"{settings.resolution_x} x {settings.resolution_y}")
        _value_row(col, "Poses", settings.pose_status)
        if settings.posed_frame_count:
            _value_row(col, "Scale", "metres" if settings.poses_metric else "arbitrary")
    else:
        layout.label(text="No capture imported", icon="INFO")
    layout.operator("vortx.estimate_poses", icon="CAMERA_DATA")
    if job is not None:
        layout.progress(text=job.status_text(), factor=job.progress.fraction, type="BAR")


def draw_pose_settings(layout: Any, settings: Any) -> None:
    layout.use_property_split = True
    layout.use_property_decorate = False
    layout.prop(settings, "sfm_matcher")
    layout.prop(settings, "sfm_max_image_side")
    layout.prop(settings, "camera_height")


def draw_reconstruction_settings(layout: Any, settings: Any) -> None:
    layout.use_property_split = True
    layout.use_property_decorate = False
    layout.prop(settings, "voxel_size")
    layout.prop(settings, "view_count")
    layout.prop(settings, "tile_size")
    layout.prop(settings, "show_tiles")


class VORTX_PT_capture(bpy.types.Panel):
    bl_idname = "VORTX_PT_capture"
    bl_label = "Capture"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY

    def draw(self, context: bpy.types.Context) -> None:
        draw_capture(self.layout, context.scene.vortx, jobs.active_job())


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
        draw_reconstruction_settings(self.layout, context.scene.vortx)


classes = (VORTX_PT_capture, VORTX_PT_pose_settings, VORTX_PT_reconstruction)
