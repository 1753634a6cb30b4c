"""Which coordinates the scene shows a capture in: the Z-up world VoRTX works in, or the capture's own.

The add-on keeps everything it computes in the engine's world and shows it through the frame empty
(scene_objects.py says how objects are placed relative to it). This module switches between the two
(`show_frame`): with Coordinates = Capture (scene.vortx.output_frame, ReconSettings.frame) the
capture's objects go under the empty, whose transform is the world -> capture similarity; with
Coordinates = World they come out from under it and the empty goes (as before the choice existed).
It sits above the modules that make those objects (cameras, point_cloud, result, tile_overlay), as it
moves all of them.

scene.vortx.capture_frame records the frames (`frame_record`: capture <-> world both ways, and world
-> shown); each result object carries the same record (`vortx_frame`, which a GLB export puts into its
extras, as `engine reconstruct` does), kept current when the coordinates change or Set Scale rescales
the world.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any, Optional

import bpy
import numpy as np
from mathutils import Matrix

from ..engine.errors import VortxError
from ..engine.recon.output_frame import FRAME_CAPTURE, FRAME_WORLD, record_in_frame
from .cameras import PROP_POSE, blender_matrix_from_pose, capture_cameras, is_capture_camera
from .point_cloud import find_point_cloud
from .result import PROP_OUTPUT_FRAME, result_objects
from .scene_objects import engine_matrix, ensure_frame_empty, find_frame_empty, place_camera, set_engine_matrix, under_frame_empty
from .tile_overlay import find_tiles_object

if TYPE_CHECKING:
    from ..engine.poses.align import Similarity

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


def _capture_objects(scene: bpy.types.Scene) -> list[bpy.types.Object]:
    """Every object the add-on made for the capture, and whatever else hangs under the frame empty."""
    objects = [*capture_cameras(scene), find_point_cloud(scene), *result_objects(scene), find_tiles_object(scene)]
    empty = find_frame_empty(scene)
    if empty is not None:
        objects += list(empty.children)
    unique: dict[str, bpy.types.Object] = {}
    for obj in objects:
        if obj is not None and obj != empty:
            unique.setdefault(obj.name, obj)
    return list(unique.values())


def show_frame(scene: bpy.types.Scene, world_change: Optional["Similarity"] = None) -> None:
    """Show the scene's capture in the coordinates scene.vortx.output_frame asks for: the capture's
    objects go under (Capture) or out from under (World) the frame empty, the empty gets the world ->
    capture similarity, the records (scene.vortx.capture_frame, each result's `vortx_frame`) say so.

    world_change: the engine's world has just been moved by it (Set Scale's scaling): the capture's own
    coordinates then map to the moved world. Capture cameras are placed from their stored poses.
    Raises VortxError, changing nothing, when Capture is asked for and the capture has no coordinates
    of its own; with nothing imported yet the choice waits for Import Capture.
    """
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
        if obj.parent is not None and not under_frame_empty(obj, empty):
            continue  # parented by the user: it follows its parent
        if is_capture_camera(obj):
            cameras.append((obj, blender_matrix_from_pose(np.array(obj[PROP_POSE], dtype=np.float64).reshape(4, 4))))
        else:
            placed.append((obj, engine_matrix(obj, scene)))

    # Writes start here; nothing below can fail on the user's input.
    if frame == FRAME_CAPTURE:
        empty = ensure_frame_empty(scene)
        empty.matrix_world = Matrix(record["world_to_output"]["matrix"])  # world -> capture
        for obj, matrix in placed:
            set_engine_matrix(obj, scene, matrix)
    else:
        for obj, matrix in placed + cameras:
            obj.parent = None
            obj.matrix_basis = Matrix(matrix.tolist())
        if empty is not None:
            bpy.data.objects.remove(empty, do_unlink=True)
    for obj, matrix in cameras:
        place_camera(obj, scene, matrix)
    settings.capture_frame = json.dumps(record)
    for obj in result_objects(scene):
        obj[PROP_OUTPUT_FRAME] = settings.capture_frame


def frame_changed(scene: bpy.types.Scene) -> None:
    """scene.vortx.output_frame's update: move the capture's objects into the chosen coordinates, or,
    when the capture has none of its own, say why (the console; the panel shows it) and go back to World."""
    try:
        show_frame(scene)
    except VortxError as error:
        print(f"VoRTX: {error}")
        scene.vortx.output_frame = WORLD  # this update again: World is always available
