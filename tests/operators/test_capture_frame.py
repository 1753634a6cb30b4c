"""Coordinates = Capture: Import Capture shows the capture, and Reconstruct / Export Result give the
mesh, in the coordinates the capture's own poses are given in (vortx_blender/frame.py), as
`engine reconstruct --frame capture` writes them.

The capture: the engine's synthetic box room (6 photos of 96 x 72, looking in across the room) with its
true poses moved by a known similarity (rotated, shifted, in units of 1.25 m, as NeRF tools leave a
scene) into a transforms.json, plus sparse points on the room's surfaces moved the same way (as a
COLMAP model would have them). The real loader, preparation and stereo reconstruction run (coarse: a
few seconds per reconstruction).
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import scene_state
from fixtures_capture import rotation_about, write_photo_folder, write_transforms_json
from fixtures_texture import read_glb

ROOM = (3.0, 3.0, 2.5)
# The capture's own frame: x_capture = KNOWN(x_truth).
KNOWN_ROTATION = rotation_about([1.0, 2.0, 0.5], 70.0)
KNOWN_TRANSLATION = np.array([2.5, -1.0, 4.0])
KNOWN_SCALE = 0.8
# Quick stereo on the tiny room: coarse voxels, few planes; every camera gets a depth map.
QUICK = {"method": "STEREO", "voxel_size": 0.1, "stereo_image_size": 64, "stereo_views": 6, "stereo_planes": 16,
         "stereo_sources": 3, "colour_views": 2}


def _known(blender):
    return blender.engine.poses.align.Similarity(KNOWN_ROTATION, KNOWN_TRANSLATION, KNOWN_SCALE)


def _box_points(count: int = 400, seed: int = 0) -> np.ndarray:
    """Points on the room box's six sides (the truth's coordinates)."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(0.0, 1.0, (count, 3)) * np.array(ROOM)
    side = rng.integers(0, 6, count)
    axis, high = side % 3, side >= 3
    points[np.arange(count), axis] = np.where(high, np.array(ROOM)[axis], 0.0)
    return points


@pytest.fixture(scope="module")
def given(blender, tmp_path_factory) -> SimpleNamespace:
    """The transforms.json capture in the known frame: its path, poses (OpenCV) and sparse points as given."""
    folder = tmp_path_factory.mktemp("capture_frame")
    synthetic = importlib.import_module(f"{blender.__name__}.engine.recon.synthetic")
    # Looking in across the room, so that the six photos overlap enough for stereo.
    truth = synthetic.make_synthetic_capture(folder / "truth", room_size=ROOM, frames=6, image_size=(96, 72),
                                             outward_deg=-45.0)
    known = _known(blender)
    poses = [known.apply_pose(frame.pose) for frame in truth.frames]
    K = truth.frames[0].K
    path = write_transforms_json(folder / "nerf" / "transforms.json",
                                 [(str(frame.image_path), pose) for frame, pose in zip(truth.frames, poses)],
                                 fl_x=K[0, 0], fl_y=K[1, 1], cx=K[0, 2], cy=K[1, 2], w=96, h=72)
    photos = folder / "photos"
    write_photo_folder(photos, 4)
    return SimpleNamespace(path=path, poses=poses, points=known.apply_points(_box_points()), photos=photos)


@pytest.fixture(scope="module")
def with_points(blender, given):
    """The real loader, with the sparse points (in the capture's frame) added to the transforms.json
    capture: the floor they show makes the world metric (Z up, floor at 0, camera height 1.5 m)."""
    real = blender.engine.capture.load_capture

    def load_capture(path, progress=None, cancel=None, **options):
        capture = real(path, progress=progress, cancel=cancel, **options)
        if Path(path) != given.path:
            return capture
        return capture.with_points(given.points, np.full((len(given.points), 3), 200, np.uint8))

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(blender.engine.capture, "load_capture", load_capture)
        yield


def _import(blender, path: Path, frame: str, **settings):
    """A fresh scene with the capture imported in `frame` (WORLD / CAPTURE) and `settings` set."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    for name, value in settings.items():
        setattr(scene.vortx, name, value)
    assert bpy.ops.vortx.import_capture(filepath=str(path), output_frame=frame) == {"FINISHED"}
    bpy.context.view_layer.update()  # children's matrix_world is computed by the depsgraph
    return scene


def _world_vertices(obj) -> np.ndarray:
    """(V, 3) float64: `obj`'s vertices in Blender's world (its matrix_world applied)."""
    local = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.vertices.foreach_get("co", local)
    matrix = np.array(obj.matrix_world, dtype=np.float64)
    return local.reshape(-1, 3).astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]


def _same_points(found: np.ndarray, expected: np.ndarray, tolerance: float = 1e-4) -> None:
    """The same point sets (an exporter may split vertices at seams or reorder them) within `tolerance`."""
    from scipy.spatial import cKDTree

    found = np.asarray(found, np.float64)
    assert len(found) >= len(expected)
    assert cKDTree(expected).query(found)[0].max() < tolerance
    assert cKDTree(found).query(expected)[0].max() < tolerance


def _recorded(blender, scene, key: str):
    entry = json.loads(scene.vortx.capture_frame)[key]
    return blender.engine.recon.output_frame.similarity_from_record(entry)


def _camera_matrices(blender, scene) -> list[np.ndarray]:
    return [np.array(obj.matrix_world, dtype=np.float64) for obj in blender.vortx_blender.cameras.capture_cameras(scene)]


def _assert_on_given_poses(blender, scene, given) -> None:
    cameras = blender.vortx_blender.cameras
    shown = _camera_matrices(blender, scene)
    assert len(shown) == len(given.poses)
    for matrix, pose in zip(shown, given.poses):
        np.testing.assert_allclose(matrix, cameras.blender_matrix_from_pose(pose), atol=1e-5)


def test_capture_coordinates_put_the_cameras_and_points_where_the_capture_has_them(blender, given, with_points) -> None:
    import bpy

    scene = _import(blender, given.path, "CAPTURE")
    settings = scene.vortx
    assert settings.output_frame == "CAPTURE"
    _assert_on_given_poses(blender, scene, given)
    record = json.loads(settings.capture_frame)
    assert record["frame"] == "capture"
    to_world, to_capture = _recorded(blender, scene, "capture_to_world"), _recorded(blender, scene, "world_to_capture")
    np.testing.assert_allclose(record["world_to_output"]["matrix"], to_capture.matrix(), atol=1e-12)
    # The engine's world is unchanged: the stored poses are the given ones moved by capture_to_world.
    posed = blender.vortx_blender.cameras.posed_capture_from_scene(scene)
    for frame, pose in zip(posed.frames, given.poses):
        np.testing.assert_allclose(frame.pose, to_world.apply_pose(pose), atol=1e-9)
    # The sparse points lie where the capture has them; the engine reads them back in its world.
    cloud = blender.vortx_blender.point_cloud.find_point_cloud(scene)
    np.testing.assert_allclose(_world_vertices(cloud), given.points, atol=1e-4)
    np.testing.assert_allclose(posed.points, to_world.apply_points(given.points), atol=1e-4)

    # Coordinates back to World: the world as before the choice existed (no empty, no parents) ...
    settings.output_frame = "WORLD"
    bpy.context.view_layer.update()
    assert blender.vortx_blender.scene_objects.find_frame_empty(scene) is None
    assert all(obj.parent is None for obj in bpy.data.objects)
    for matrix, frame in zip(_camera_matrices(blender, scene), posed.frames):
        np.testing.assert_allclose(matrix, blender.vortx_blender.cameras.blender_matrix_from_pose(frame.pose), atol=1e-5)
    np.testing.assert_allclose(_world_vertices(cloud), posed.points, atol=1e-4)
    assert json.loads(settings.capture_frame)["frame"] == "world"
    # ... and to Capture again.
    settings.output_frame = "CAPTURE"
    bpy.context.view_layer.update()
    _assert_on_given_poses(blender, scene, given)
    np.testing.assert_allclose(_world_vertices(cloud), given.points, atol=1e-4)


def test_set_scale_in_capture_coordinates_scales_the_world_not_the_capture(blender, given, with_points) -> None:
    import bpy

    scene = _import(blender, given.path, "CAPTURE")
    scale = blender.vortx_blender.scale
    before = blender.vortx_blender.cameras.posed_capture_from_scene(scene)
    first, second = (f.pose[:3, 3] for f in before.frames[:2])
    change = scale.set_scale(scene, [scale.PickedPoint("a", first), scale.PickedPoint("b", second)],
                             3.0 * float(np.linalg.norm(first - second)))
    assert change.factor == pytest.approx(3.0) and "capture's own coordinates" in change.description
    bpy.context.view_layer.update()
    _assert_on_given_poses(blender, scene, given)  # the capture's coordinates do not move
    after = blender.vortx_blender.cameras.posed_capture_from_scene(scene)
    for old, new in zip(before.frames, after.frames):
        np.testing.assert_allclose(new.pose[:3, 3], 3.0 * old.pose[:3, 3], atol=1e-9)  # the world is 3x
    np.testing.assert_allclose(after.points, 3.0 * before.points, atol=1e-4)
    to_world = _recorded(blender, scene, "capture_to_world")
    for frame, pose in zip(after.frames, given.poses):
        np.testing.assert_allclose(frame.pose, to_world.apply_pose(pose), atol=1e-6)


@pytest.fixture(scope="module")
def runs(blender, given, with_points, tmp_path_factory) -> SimpleNamespace:
    """The capture reconstructed in World, then in Capture (the real stereo method, coarse); the Capture
    scene's result exported (GLB, PLY), its tiles and then its texture baked."""
    import bpy

    results, export = blender.vortx_blender.result, blender.vortx_blender.export
    out = tmp_path_factory.mktemp("capture_frame_runs")

    scene = _import(blender, given.path, "WORLD", **QUICK)
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    (world,) = results.result_objects(scene)
    world_vertices = _world_vertices(world)

    scene = _import(blender, given.path, "CAPTURE", **QUICK)
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    (obj,) = results.result_objects(scene)
    bpy.context.view_layer.update()
    glb = export.export_result(obj, out / "room.glb", scene.view_layers[0])
    ply = export.export_result(obj, out / "room.ply", scene.view_layers[0])
    request = blender.vortx_blender.texture.request_from_scene(scene, obj, bpy.context.evaluated_depsgraph_get())
    assert bpy.ops.vortx.bake_tiles() == {"FINISHED"}
    bpy.context.view_layer.update()
    overlay = blender.vortx_blender.tile_overlay.current(scene)
    baked = blender.vortx_blender.tile_overlay.find_tiles_object(scene)
    tiles = (_world_vertices(baked), overlay.corners.reshape(-1, 3).astype(np.float64))
    vertices = _world_vertices(obj)
    # Bake Texture (small): the baked mesh stays where the result was, in the capture's coordinates.
    scene.vortx.texture_size, scene.vortx.face_budget = 512, 200
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    bpy.context.view_layer.update()
    textured = (_world_vertices(obj), obj.parent.name if obj.parent else None, len(obj.data.uv_layers))
    return SimpleNamespace(
        world_vertices=world_vertices, vertices=vertices, settings=json.loads(obj["vortx_settings"]),
        record=json.loads(obj["vortx_frame"]), to_capture=_recorded(blender, scene, "world_to_capture"), glb=glb,
        ply=ply, bake_vertices=request.mesh.vertices, parent=obj.parent.name if obj.parent else None, tiles=tiles,
        textured=textured,
    )


def test_result_lies_in_the_capture_coordinates(blender, runs) -> None:
    assert len(runs.vertices) == len(runs.world_vertices) > 100
    # The same reconstruction as in World, shown through the recorded world -> capture similarity.
    expected = runs.to_capture.apply_points(runs.world_vertices)
    np.testing.assert_allclose(runs.vertices, expected, atol=1e-4)
    assert runs.parent == blender.vortx_blender.scene_objects.FRAME_EMPTY_NAME
    # The result records its coordinates: in its settings and as the engine's frame record.
    assert runs.settings["frame"] == "capture"
    assert runs.record["frame"] == "capture"
    np.testing.assert_allclose(runs.record["world_to_output"]["matrix"], runs.to_capture.matrix(), atol=1e-12)
    # Bake Texture reads the mesh in the engine's world, where the cameras it projects the photos from are.
    np.testing.assert_allclose(runs.bake_vertices, runs.world_vertices, atol=1e-4)
    # Bake Texture's mesh (decimated to 200 faces) stays in the capture's coordinates, on the result's surface.
    baked, parent, uv_layers = runs.textured
    assert parent == runs.parent and uv_layers == 1 and len(baked) < len(runs.vertices)
    from scipy.spatial import cKDTree

    voxel = QUICK["voxel_size"] * runs.to_capture.scale  # a voxel in the capture's units
    assert cKDTree(runs.vertices).query(baked)[0].max() < 2 * voxel
    # The baked tile boxes (Bake Tiles) sit around the mesh in the capture's coordinates too.
    shown, corners = runs.tiles
    np.testing.assert_allclose(shown, runs.to_capture.apply_points(corners), atol=1e-4)


def test_exported_mesh_is_in_the_capture_coordinates(blender, runs) -> None:
    import bpy

    # PLY: the file's coordinates are the capture's.
    _same_points(blender.engine.mesh_io.read_ply(runs.ply).vertices, runs.vertices)
    # GLB: Blender's importer (which undoes glTF's Y up) gives back the capture's coordinates; the
    # node's extras carry the frame record, as `engine reconstruct`'s GLB does.
    document, _ = read_glb(runs.glb)
    (node,) = [n for n in document["nodes"] if "mesh" in n]
    assert json.loads(node["extras"]["vortx_frame"])["frame"] == "capture"
    bpy.ops.wm.read_homefile(use_empty=True)
    assert bpy.ops.import_scene.gltf(filepath=str(runs.glb)) == {"FINISHED"}
    bpy.context.view_layer.update()
    (imported,) = [obj for obj in bpy.context.scene.objects if obj.type == "MESH"]
    _same_points(_world_vertices(imported), runs.vertices)


def test_capture_coordinates_are_refused_for_photos_without_poses(blender, given, with_points) -> None:
    import bpy

    scene = _import(blender, given.path, "WORLD")
    before = scene_state(scene)
    with pytest.raises(RuntimeError, match="Coordinates 'Capture' is not available: no frame of the capture has a pose"):
        bpy.ops.vortx.import_capture(filepath=str(given.photos), output_frame="CAPTURE")
    assert scene_state(scene) == before

    # Imported in World, a photos-only capture cannot be switched to Capture: the setting stays World,
    # the panel greys the choice out and says why, Estimate Poses is offered.
    assert bpy.ops.vortx.import_capture(filepath=str(given.photos)) == {"FINISHED"}
    settings = scene.vortx
    before = scene_state(scene)
    settings.output_frame = "CAPTURE"
    assert settings.output_frame == "WORLD" and scene_state(scene) == before
    from fixtures_blender_ui import RecordingLayout

    calls: list = []
    importlib.import_module(f"{blender.__name__}.ui.panels").draw_capture(RecordingLayout(calls), settings, None)
    assert ("set", {"enabled": False}) in calls
    # One line says so; hovering it (its tooltip) says why.
    (note,) = [c[1] for c in calls if c[0] == "operator" and c[1].get("text") == "No capture coordinates"]
    assert note["operator"] == "vortx.explain"
    assert note["properties"]["text"] == "No capture coordinates: no frame of the capture has a pose"
    assert bpy.ops.vortx.estimate_poses.poll()


def test_estimate_poses_is_refused_while_the_capture_coordinates_are_shown(blender, given, with_points) -> None:
    import bpy

    _import(blender, given.path, "CAPTURE")
    assert not bpy.ops.vortx.estimate_poses.poll()
    with pytest.raises(RuntimeError, match="Estimate Poses cannot keep: structure from motion estimated the poses"):
        bpy.ops.vortx.estimate_poses()


def test_scripts_without_the_option_use_the_scene_setting(blender, given, with_points) -> None:
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.vortx.output_frame = "CAPTURE"  # nothing imported yet: the choice waits for the import
    assert blender.vortx_blender.scene_objects.find_frame_empty(scene) is None
    assert bpy.ops.vortx.import_capture(filepath=str(given.path)) == {"FINISHED"}
    bpy.context.view_layer.update()
    _assert_on_given_poses(blender, scene, given)
