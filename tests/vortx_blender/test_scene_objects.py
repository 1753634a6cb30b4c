"""Where the add-on's objects live (vortx_blender/scene_objects.py): collections found by their tag, and
objects placed in the engine's world whichever coordinates the scene shows (with a frame empty, as
Coordinates = Capture makes it, or without)."""

from __future__ import annotations

import numpy as np

from engine.poses.align import Similarity


def _world_to_capture() -> np.ndarray:
    """(4, 4) a similarity as a capture's own coordinates often are: turned, shifted and 1.25 x larger."""
    angle = np.radians(30.0)
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    return Similarity(rotation, np.array([0.5, -2.0, 1.0]), 1.25).matrix()


def _translation(x: float, y: float, z: float) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, 3] = (x, y, z)
    return matrix


def _new_object(scene, name: str):
    import bpy

    obj = bpy.data.objects.new(name, bpy.data.meshes.new(name))
    scene.collection.objects.link(obj)
    return obj


def _evaluated_world(obj) -> np.ndarray:
    import bpy

    bpy.context.view_layer.update()
    return np.array(obj.matrix_world, dtype=np.float64)


def test_a_collection_is_found_by_its_tag_after_the_user_renames_it(blender, empty_scene) -> None:
    scene_objects = blender.vortx_blender.scene_objects
    assert scene_objects.find_capture_collection(empty_scene) is None
    made = scene_objects.ensure_capture_collection(empty_scene)
    made.name = "Kitchen photos"
    assert scene_objects.ensure_capture_collection(empty_scene) == made  # no second collection
    assert scene_objects.find_tagged_collection(empty_scene, scene_objects.CAPTURE_COLLECTION_TAG) == made
    assert [c.name for c in empty_scene.collection.children] == ["Kitchen photos"]


def test_without_a_frame_empty_the_engine_world_is_the_scene(blender, empty_scene) -> None:
    scene_objects = blender.vortx_blender.scene_objects
    obj = _new_object(empty_scene, "Result")
    scene_objects.set_engine_matrix(obj, empty_scene, _translation(1.0, 2.0, 0.5))
    scene_objects.place_new(obj, empty_scene)  # nothing to hang under: stays where it is
    assert obj.parent is None
    np.testing.assert_allclose(_evaluated_world(obj), _translation(1.0, 2.0, 0.5), atol=1e-6)
    np.testing.assert_allclose(scene_objects.engine_matrix(obj, empty_scene), _translation(1.0, 2.0, 0.5), atol=1e-6)


def test_objects_are_placed_in_the_engine_world_under_the_frame_empty(blender, empty_scene) -> None:
    from mathutils import Matrix

    scene_objects = blender.vortx_blender.scene_objects
    shown = _world_to_capture()
    empty = scene_objects.ensure_frame_empty(empty_scene)
    empty.matrix_world = Matrix(shown.tolist())
    assert scene_objects.ensure_frame_empty(empty_scene) == empty
    assert scene_objects.find_frame_empty(empty_scene) == empty

    # A new object made in the engine's world is shown through the empty, and reads back unchanged.
    obj = _new_object(empty_scene, "Sparse Points")
    obj.matrix_basis = Matrix(_translation(1.0, 2.0, 0.5).tolist())
    scene_objects.place_new(obj, empty_scene)
    assert scene_objects.under_frame_empty(obj, empty)
    np.testing.assert_allclose(scene_objects.engine_matrix(obj, empty_scene), _translation(1.0, 2.0, 0.5), atol=1e-6)
    np.testing.assert_allclose(_evaluated_world(obj), shown @ _translation(1.0, 2.0, 0.5), atol=1e-5)

    # An object the user parented elsewhere keeps its parent and still lands at the engine matrix asked for.
    holder = _new_object(empty_scene, "User Parent")
    moved = _new_object(empty_scene, "Tiles")
    moved.parent = holder
    scene_objects.set_engine_matrix(moved, empty_scene, _translation(-1.0, 0.0, 2.0))
    assert moved.parent == holder
    _evaluated_world(moved)
    np.testing.assert_allclose(scene_objects.engine_matrix(moved, empty_scene), _translation(-1.0, 0.0, 2.0), atol=1e-5)


def test_a_camera_stays_rigid_in_scaled_capture_coordinates(blender, empty_scene) -> None:
    import bpy
    from mathutils import Matrix

    scene_objects = blender.vortx_blender.scene_objects
    shown = _world_to_capture()
    scene_objects.ensure_frame_empty(empty_scene).matrix_world = Matrix(shown.tolist())
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    empty_scene.collection.objects.link(camera)
    pose = _translation(2.0, 1.0, 1.6)
    scene_objects.place_camera(camera, empty_scene, pose)
    world = _evaluated_world(camera)
    # Its own axes keep unit length (a scaled camera would project differently), and it stands where
    # the capture's coordinates put that pose.
    np.testing.assert_allclose(np.linalg.norm(world[:3, :3], axis=0), 1.0, atol=1e-6)
    np.testing.assert_allclose(world[:3, 3], (shown @ pose)[:3, 3], atol=1e-5)
