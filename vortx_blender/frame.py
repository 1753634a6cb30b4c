"""The coordinates the scene shows a capture in: the Z-up world VoRTX works in, or the capture's own.

The engine reconstructs in its prepared world (Z up, floor at z = 0, metres; engine/recon/output_frame.py)
and the add-on keeps everything it computes there: the cameras' stored poses, the sparse points, the
result meshes, the tiles. Coordinates = Capture (scene.vortx.output_frame, ReconSettings.frame) shows
that world in the capture's own coordinates (a NeRF transforms.json's, a COLMAP model's) through one
empty, "VoRTX Capture Frame" in the capture collection, whose transform is the world -> capture
similarity. The objects the add-on makes for the capture (cameras, sparse points, results, baked
tiles) are its children, and their transforms relative to it are their world ones. So a camera's
matrix_world is the capture's own pose, a result lies over the pipeline's own cameras, and exporters
that apply world transforms (Export Result, Blender's own) write capture coordinates. The add-on reads
and places its objects relative to the empty (`engine_matrix`, `set_engine_matrix`), so every
operator works in the same world whichever coordinates are shown. With Coordinates = World there is
no empty (as before the choice existed).

scene.vortx.capture_frame records the frames (`frame_record`: capture <-> world both ways, and world
-> shown); each result object carries the same record (`vortx_frame`, which a GLB export puts into its
extras, as `engine reconstruct` does), kept current when the coordinates change or Set Scale rescales
the world.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any, Optional

import numpy as np

from ..engine.errors import VortxError
from ..engine.recon.output_frame import FRAME_CAPTURE, FRAME_WORLD, record_in_frame

if TYPE_CHECKING:
    import bpy

    from ..engine.poses.align import Similarity

FRAME_EMPTY_NAME = "VoRTX Capture Frame"
FRAME_EMPTY_TAG = "vortx_capture_frame"  # custom property marking the empty we own
CAPTURE = FRAME_CAPTURE.upper()  # scene.vortx.output_frame's enum identifiers
WORLD = FRAME_WORLD.upper()


def unavailable(reason: str) -> VortxError:
    """The error refusing Coordinates = Capture, with the engine's reason (`capture_frame_missing`)."""
    return VortxError(f"Coordinates 'Capture' is not available: {reason}. Choose World (Capture panel > Coordinates), "
                      "or import the capture with poses of its own (a transforms.json, a COLMAP model)")


def shown_frame(settings: Any) -> str:
    """The engine's name (FRAME_WORLD / FRAME_CAPTURE) of the coordinates scene.vortx asks for."""
    return str(settings.output_frame).lower()


def frame_record(settings: Any) -> Optional[dict[str, Any]]:
    """scene.vortx.capture_frame as a dict (`engine.recon.output_frame.frame_record`), or None before an import."""
    return json.loads(settings.capture_frame) if settings.capture_frame else None


def capture_frame_note(settings: Any) -> Optional[str]:
    """Why the imported capture cannot be shown in its own coordinates (no poses, or poses from structure
    from motion), or None when it can or nothing is imported."""
    record = frame_record(settings)
    if record is None or record.get("capture_to_world") is not None:
        return None
    return record.get("note") or "the capture has no coordinates of its own"


# --- the empty and the objects placed relative to it -----------------------------------------------------


def find_frame_empty(scene: "bpy.types.Scene") -> Optional["bpy.types.Object"]:
    """The capture collection's frame empty, or None (Coordinates = World)."""
    from .cameras import find_capture_collection

    collection = find_capture_collection(scene)
    if collection is None:
        return None
    return next((obj for obj in collection.objects if obj.type == "EMPTY" and obj.get(FRAME_EMPTY_TAG)), None)


def _matrix(value: Any) -> np.ndarray:
    return np.array(value, dtype=np.float64)


def _framed(obj: "bpy.types.Object", empty: Optional["bpy.types.Object"]) -> bool:
    return empty is not None and obj.parent == empty and obj.parent_type == "OBJECT"


def shown_from_engine(scene: "bpy.types.Scene") -> np.ndarray:
    """(4, 4): where the engine's world lies in the scene (the frame empty's transform; identity for World)."""
    empty = find_frame_empty(scene)
    return np.eye(4) if empty is None else _matrix(empty.matrix_world)


def engine_matrix(obj: "bpy.types.Object", scene: "bpy.types.Scene") -> np.ndarray:
    """(4, 4) float64: the transform from `obj`'s local coordinates to the engine's world, whichever
    coordinates the scene shows (a child of the frame empty: its transform relative to the empty, which
    is current even before the depsgraph evaluates it; any other object: its matrix_world seen from the empty)."""
    empty = find_frame_empty(scene)
    if _framed(obj, empty):
        return _matrix(obj.matrix_parent_inverse) @ _matrix(obj.matrix_basis)
    return np.linalg.inv(shown_from_engine(scene)) @ _matrix(obj.matrix_world)


def set_engine_matrix(obj: "bpy.types.Object", scene: "bpy.types.Scene", matrix: np.ndarray) -> None:
    """Place `obj` so that its local coordinates map to the engine's world by `matrix` (4, 4): a child of
    the frame empty when there is one (unless the user parented it elsewhere), else at that matrix_world."""
    from mathutils import Matrix

    empty = find_frame_empty(scene)
    if empty is not None and (obj.parent is None or obj.parent == empty):
        obj.parent = empty
        obj.parent_type = "OBJECT"
        obj.matrix_parent_inverse = Matrix.Identity(4)
        obj.matrix_basis = Matrix(np.asarray(matrix, dtype=np.float64).tolist())
    else:
        obj.matrix_world = Matrix((shown_from_engine(scene) @ np.asarray(matrix, dtype=np.float64)).tolist())


def place_new(obj: "bpy.types.Object", scene: "bpy.types.Scene") -> None:
    """A new object whose transform is in the engine's world (a result, the sparse points, the tiles):
    under the frame empty when the scene shows the capture's coordinates."""
    if find_frame_empty(scene) is not None:
        set_engine_matrix(obj, scene, _matrix(obj.matrix_basis))


def place_camera(obj: "bpy.types.Object", scene: "bpy.types.Scene", camera_matrix: np.ndarray) -> None:
    """A capture camera at `camera_matrix` (4, 4), its Blender camera matrix in the engine's world. The
    frame's scale is undone on the camera, so its matrix_world is rigid in the coordinates shown: with
    Capture, exactly the capture's own pose (in Blender's camera axes)."""
    shown = shown_from_engine(scene)
    unscale = 1.0 / float(np.cbrt(np.linalg.det(shown[:3, :3])))
    set_engine_matrix(obj, scene, np.asarray(camera_matrix, dtype=np.float64) @ np.diag([unscale, unscale, unscale, 1.0]))


def _capture_objects(scene: "bpy.types.Scene") -> list["bpy.types.Object"]:
    """Every object the add-on made for the capture, and whatever else hangs under the frame empty."""
    from .cameras import capture_cameras
    from .point_cloud import find_point_cloud
    from .result import result_objects
    from .tile_overlay import find_tiles_object

    objects = [*capture_cameras(scene), find_point_cloud(scene), *result_objects(scene), find_tiles_object(scene)]
    empty = find_frame_empty(scene)
    if empty is not None:
        objects += list(empty.children)
    unique: dict[str, "bpy.types.Object"] = {}
    for obj in objects:
        if obj is not None and obj != empty:
            unique.setdefault(obj.name, obj)
    return list(unique.values())


def _ensure_frame_empty(scene: "bpy.types.Scene") -> "bpy.types.Object":
    import bpy

    from .cameras import ensure_capture_collection

    empty = find_frame_empty(scene)
    if empty is None:
        empty = bpy.data.objects.new(FRAME_EMPTY_NAME, None)
        empty[FRAME_EMPTY_TAG] = True
        empty.empty_display_type = "ARROWS"  # the Z-up world's axes at its origin (on the floor)
        empty.empty_display_size = 0.5
        ensure_capture_collection(scene).objects.link(empty)
    return empty


def show_frame(scene: "bpy.types.Scene", world_change: Optional["Similarity"] = None) -> None:
    """Show the scene's capture in the coordinates scene.vortx.output_frame asks for: the capture's
    objects go under (Capture) or out from under (World) the frame empty, the empty gets the world ->
    capture similarity, the records (scene.vortx.capture_frame, each result's `vortx_frame`) say so.

    world_change: the engine's world has just been moved by it (Set Scale's scaling): the capture's own
    coordinates then map to the moved world. Capture cameras are placed from their stored poses.
    Raises VortxError, changing nothing, when Capture is asked for and the capture has no coordinates
    of its own; with nothing imported yet the choice waits for Import Capture.
    """
    from mathutils import Matrix

    from .cameras import PROP_POSE, blender_matrix_from_pose, capture_cameras, is_capture_camera
    from .result import PROP_OUTPUT_FRAME, result_objects

    settings = scene.vortx
    frame = shown_frame(settings)
    record = frame_record(settings)
    if record is None:
        if frame == FRAME_CAPTURE and capture_cameras(scene):
            raise VortxError("Coordinates 'Capture' is not available: this scene's capture cameras have no record of the "
                             "capture's own coordinates (made by an older VoRTX): import the capture again")
        return
    try:
        record = record_in_frame(record, frame, world_change)
    except VortxError as error:
        raise unavailable(str(error)) from None
    empty = find_frame_empty(scene)
    placed, cameras = [], []  # (object, engine matrix), read before anything moves; the cameras from their poses
    for obj in _capture_objects(scene):
        if obj.parent is not None and not _framed(obj, empty):
            continue  # parented by the user: it follows its parent
        if is_capture_camera(obj):
            cameras.append((obj, blender_matrix_from_pose(np.array(obj[PROP_POSE], dtype=np.float64).reshape(4, 4))))
        else:
            placed.append((obj, engine_matrix(obj, scene)))

    # Writes start here; nothing below can fail on the user's input.
    if frame == FRAME_CAPTURE:
        empty = _ensure_frame_empty(scene)
        empty.matrix_world = Matrix(record["world_to_output"]["matrix"])  # world -> capture
        for obj, matrix in placed:
            set_engine_matrix(obj, scene, matrix)
    else:
        for obj, matrix in placed + cameras:
            obj.parent = None
            obj.matrix_basis = Matrix(matrix.tolist())
        if empty is not None:
            import bpy

            bpy.data.objects.remove(empty, do_unlink=True)
    for obj, matrix in cameras:
        place_camera(obj, scene, matrix)
    settings.capture_frame = json.dumps(record)
    for obj in result_objects(scene):
        obj[PROP_OUTPUT_FRAME] = settings.capture_frame


def frame_changed(scene: "bpy.types.Scene") -> None:
    """scene.vortx.output_frame's update: move the capture's objects into the chosen coordinates, or,
    when the capture has none of its own, say why (the console; the panel shows it) and go back to World."""
    try:
        show_frame(scene)
    except VortxError as error:
        print(f"VoRTX: {error}")
        scene.vortx.output_frame = WORLD  # this update again: World is always available
