"""Where the add-on's objects live in a scene: its collections, found by a tag, and the engine's world
inside the scene, where every object it makes is placed. The bottom of vortx_blender: the modules that
make objects (cameras, point_cloud, result, tile_overlay) build on it, and it imports none of them.

Collections: the add-on owns a few collections ("VoRTX Capture", "VoRTX Result"), each marked with a
custom property, so renaming one is fine (`find_tagged_collection`, `ensure_tagged_collection`).

The engine reconstructs in its prepared world (Z up, floor at z = 0, metres; engine/recon/output_frame.py)
and the add-on keeps everything it computes there: the cameras' stored poses, the sparse points, the
result meshes, the tiles. Coordinates = Capture (scene.vortx.output_frame, ReconSettings.frame) shows
that world in the capture's own coordinates (a NeRF transforms.json's, a COLMAP model's) through one
empty, "VoRTX Capture Frame" in the capture collection, whose transform is the world -> capture
similarity. The objects the add-on makes for the capture (cameras, sparse points, results, baked
tiles) are its children, and their transforms relative to it are their world ones. So a camera's
matrix_world is the capture's own pose, a result lies over the pipeline's own cameras, and exporters
that apply world transforms (Export Result, Blender's own) write capture coordinates. The add-on reads
and places its objects relative to the empty (`engine_matrix`, `set_engine_matrix`, `place_new`,
`place_camera`), so every operator works in the same world whichever coordinates are shown. With
Coordinates = World there is no empty. Switching between the two is frame.py's.
"""

from __future__ import annotations

from typing import Optional

import bpy
import numpy as np
from mathutils import Matrix

CAPTURE_COLLECTION_NAME = "VoRTX Capture"
CAPTURE_COLLECTION_TAG = "vortx_capture"  # custom property marking the capture collection we own
FRAME_EMPTY_NAME = "VoRTX Capture Frame"
FRAME_EMPTY_TAG = "vortx_capture_frame"  # custom property marking the empty we own


# --- collections ------------------------------------------------------------------------------------------


def find_tagged_collection(scene: bpy.types.Scene, tag: str) -> Optional[bpy.types.Collection]:
    """The collection of `scene` marked with custom property `tag` (found by tag, so renaming it is fine)."""
    for collection in scene.collection.children_recursive:
        if collection.get(tag):
            return collection
    return None


def ensure_tagged_collection(scene: bpy.types.Scene, tag: str, name: str) -> bpy.types.Collection:
    """`find_tagged_collection`, or a new collection `name` marked with `tag` in the scene."""
    collection = find_tagged_collection(scene, tag)
    if collection is None:
        collection = bpy.data.collections.new(name)
        collection[tag] = True
        scene.collection.children.link(collection)
    return collection


def find_capture_collection(scene: bpy.types.Scene) -> Optional[bpy.types.Collection]:
    """The collection this extension made for `scene`'s capture."""
    return find_tagged_collection(scene, CAPTURE_COLLECTION_TAG)


def ensure_capture_collection(scene: bpy.types.Scene) -> bpy.types.Collection:
    """The capture collection of `scene`, made when there is none."""
    return ensure_tagged_collection(scene, CAPTURE_COLLECTION_TAG, CAPTURE_COLLECTION_NAME)


# --- the frame empty and the objects placed relative to it ----------------------------------------------


def find_frame_empty(scene: bpy.types.Scene) -> Optional[bpy.types.Object]:
    """The capture collection's frame empty, or None (Coordinates = World)."""
    collection = find_capture_collection(scene)
    if collection is None:
        return None
    return next((obj for obj in collection.objects if obj.type == "EMPTY" and obj.get(FRAME_EMPTY_TAG)), None)


def ensure_frame_empty(scene: bpy.types.Scene) -> bpy.types.Object:
    """The frame empty, made (at identity, in the capture collection) when there is none."""
    empty = find_frame_empty(scene)
    if empty is None:
        empty = bpy.data.objects.new(FRAME_EMPTY_NAME, None)
        empty[FRAME_EMPTY_TAG] = True
        empty.empty_display_type = "ARROWS"  # the Z-up world's axes at its origin (on the floor)
        empty.empty_display_size = 0.5
        ensure_capture_collection(scene).objects.link(empty)
    return empty


def _matrix(value: object) -> np.ndarray:
    return np.array(value, dtype=np.float64)


def under_frame_empty(obj: bpy.types.Object, empty: Optional[bpy.types.Object]) -> bool:
    """Whether `obj` hangs directly under the frame `empty` (so its transform relative to it is its engine one)."""
    return empty is not None and obj.parent == empty and obj.parent_type == "OBJECT"


def shown_from_engine(scene: bpy.types.Scene) -> np.ndarray:
    """(4, 4): where the engine's world lies in the scene (the frame empty's transform; identity for World)."""
    empty = find_frame_empty(scene)
    return np.eye(4) if empty is None else _matrix(empty.matrix_world)


def engine_matrix(obj: bpy.types.Object, scene: bpy.types.Scene) -> np.ndarray:
    """(4, 4) float64: the transform from `obj`'s local coordinates to the engine's world, whichever
    coordinates the scene shows (a child of the frame empty: its transform relative to the empty, which
    is current even before the depsgraph evaluates it; any other object: its matrix_world seen from the empty)."""
    empty = find_frame_empty(scene)
    if under_frame_empty(obj, empty):
        return _matrix(obj.matrix_parent_inverse) @ _matrix(obj.matrix_basis)
    return np.linalg.inv(shown_from_engine(scene)) @ _matrix(obj.matrix_world)


def set_engine_matrix(obj: bpy.types.Object, scene: bpy.types.Scene, matrix: np.ndarray) -> None:
    """Place `obj` so that its local coordinates map to the engine's world by `matrix` (4, 4): a child of
    the frame empty when there is one (unless the user parented it elsewhere), else at that matrix_world."""
    empty = find_frame_empty(scene)
    if empty is not None and (obj.parent is None or obj.parent == empty):
        obj.parent = empty
        obj.parent_type = "OBJECT"
        obj.matrix_parent_inverse = Matrix.Identity(4)
        obj.matrix_basis = Matrix(np.asarray(matrix, dtype=np.float64).tolist())
    else:
        obj.matrix_world = Matrix((shown_from_engine(scene) @ np.asarray(matrix, dtype=np.float64)).tolist())


def place_new(obj: bpy.types.Object, scene: bpy.types.Scene) -> None:
    """A new object whose transform is in the engine's world (a result, the sparse points, the tiles):
    under the frame empty when the scene shows the capture's coordinates."""
    if find_frame_empty(scene) is not None:
        set_engine_matrix(obj, scene, _matrix(obj.matrix_basis))


def place_camera(obj: bpy.types.Object, scene: bpy.types.Scene, camera_matrix: np.ndarray) -> None:
    """A capture camera at `camera_matrix` (4, 4), its Blender camera matrix in the engine's world. The
    frame's scale is undone on the camera, so its matrix_world is rigid in the coordinates shown: with
    Capture, exactly the capture's own pose (in Blender's camera axes)."""
    shown = shown_from_engine(scene)
    unscale = 1.0 / float(np.cbrt(np.linalg.det(shown[:3, :3])))
    set_engine_matrix(obj, scene, np.asarray(camera_matrix, dtype=np.float64) @ np.diag([unscale, unscale, unscale, 1.0]))
