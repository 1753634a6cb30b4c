"""Scene settings (`scene.vortx`): what was imported and how to reconstruct it.

Everything lives on the Scene, not in add-on preferences, so a .blend file carries its own capture
path and reconstruction settings and re-opening it later reproduces the same run. The capture
summary fields (format, frame counts, resolution, pose status) are written by the operators only;
the panel shows them as labels so users do not edit them by accident. (`options={'READ_ONLY'}` would
say so in the RNA, but it only exists from Blender 5.0 and we support 4.2.)

No `from __future__ import annotations` here: bpy reads the property annotations as objects.
"""

from typing import TYPE_CHECKING

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

if TYPE_CHECKING:
    from ..engine.capture import Capture

# The three VoRTX levels are 4x, 2x and 1x the fine voxel; the fine one is the user's knob.
DEFAULT_VOXEL_SIZE = 0.04
DEFAULT_VIEW_COUNT = 60
DEFAULT_TILE_SIZE = 96
DEFAULT_CAMERA_HEIGHT = 1.5
DEFAULT_MAX_IMAGE_SIDE = 1024  # engine.poses.SfmOptions.max_side: full registration on real photos at 4x less cost

MATCHER_ITEMS = [
    ("AUTO", "Auto", "Sequential matching for video-like captures, exhaustive for small unordered sets"),
    ("SEQUENTIAL", "Sequential", "Match each photo with its neighbours in capture order (fast, for walk-throughs)"),
    ("EXHAUSTIVE", "Exhaustive", "Match every pair of photos (slow for many photos, robust for unordered sets)"),
]


class VortxSceneSettings(bpy.types.PropertyGroup):
    # --- capture summary, written by vortx.import_capture / vortx.estimate_poses ---
    capture_path: StringProperty(
        name="Capture",
        description="Folder or file (transforms.json, video, ...) the capture was imported from",
        subtype="FILE_PATH",
    )
    capture_format: StringProperty(name="Format", description="Capture layout detected on import")
    frame_count: IntProperty(name="Frames", description="Number of photos in the capture", min=0)
    posed_frame_count: IntProperty(name="Posed Frames", description="Photos that have a camera pose", min=0)
    resolution_x: IntProperty(name="Width", description="Photo width in pixels", min=0, subtype="PIXEL")
    resolution_y: IntProperty(name="Height", description="Photo height in pixels", min=0, subtype="PIXEL")
    poses_metric: BoolProperty(
        name="Metric Poses",
        description="Camera positions are in metres (from the capture format or scaled by the camera height)",
    )
    pose_status: StringProperty(name="Poses", description="Where the camera poses come from, or what is missing")

    # --- reconstruction settings ---
    voxel_size: FloatProperty(
        name="Voxel Size",
        description="Finest voxel edge; the coarser levels are 2x and 4x this (VoRTX was trained at 4 cm)",
        default=DEFAULT_VOXEL_SIZE,
        min=0.005,
        max=0.5,
        soft_min=0.02,
        soft_max=0.16,
        step=1,
        precision=3,
        subtype="DISTANCE",
        unit="LENGTH",
    )
    view_count: IntProperty(
        name="Views per Tile",
        description="Number of photos fused into each tile (more: better detail, more memory and time)",
        default=DEFAULT_VIEW_COUNT,
        min=1,
        max=500,
        soft_max=200,
    )
    tile_size: IntProperty(
        name="Tile Size",
        description="Edge of a reconstruction tile in fine voxels (smaller: less memory per step)",
        default=DEFAULT_TILE_SIZE,
        min=8,
        max=512,
        step=8,
    )
    show_tiles: BoolProperty(
        name="Show Tiles",
        description="Draw the reconstruction tiles and their progress in the viewport",
        default=True,
    )

    # --- structure-from-motion settings (vortx.estimate_poses) ---
    sfm_matcher: EnumProperty(name="Matcher", description="How photo pairs are chosen for matching", items=MATCHER_ITEMS, default="AUTO")
    sfm_max_image_side: IntProperty(
        name="Max Image Side",
        description="Photos are downscaled to this longest side for feature extraction (smaller: faster)",
        default=DEFAULT_MAX_IMAGE_SIDE,
        min=256,
        max=8192,
        subtype="PIXEL",
    )
    camera_height: FloatProperty(
        name="Camera Height",
        description="Typical height of the camera above the floor; sets the metric scale of estimated poses",
        default=DEFAULT_CAMERA_HEIGHT,
        min=0.1,
        max=10.0,
        subtype="DISTANCE",
        unit="LENGTH",
    )


def capture_summary(capture: "Capture", path: str, pose_status: str | None = None) -> dict[str, object]:
    """The scene.vortx summary values describing `capture`, without touching Blender data.

    Computed before anything is written so that a failure in between cannot leave a half-updated
    panel (the "failed import changes nothing" rule).
    """
    width, height = capture.resolution
    posed = len(capture.posed_frames)
    total = len(capture.frames)
    if pose_status is None:
        if posed == 0:
            pose_status = "No poses: run Estimate Poses"
        elif posed == total:
            pose_status = f"All {total} posed ({capture.format})"
        else:
            pose_status = f"{posed} of {total} posed ({capture.format})"
    return {
        "capture_path": path,
        "capture_format": capture.format,
        "frame_count": total,
        "posed_frame_count": posed,
        "resolution_x": int(width),
        "resolution_y": int(height),
        "poses_metric": bool(capture.metric) and posed > 0,
        "pose_status": pose_status,
    }


def write_summary(settings: VortxSceneSettings, summary: dict[str, object]) -> None:
    for name, value in summary.items():
        setattr(settings, name, value)


def settings_values(settings: VortxSceneSettings) -> dict[str, object]:
    """Every scene.vortx property as plain Python values (for snapshots, logs and tests)."""
    values: dict[str, object] = {}
    for prop in settings.bl_rna.properties:
        if prop.identifier in ("rna_type", "name"):  # built into every PropertyGroup, not a setting
            continue
        value = getattr(settings, prop.identifier)
        values[prop.identifier] = tuple(value) if hasattr(value, "__len__") and not isinstance(value, str) else value
    return values


classes = (VortxSceneSettings,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.vortx = PointerProperty(type=VortxSceneSettings, name="VoRTX", description="VoRTX capture and reconstruction settings")


def unregister() -> None:
    del bpy.types.Scene.vortx
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
