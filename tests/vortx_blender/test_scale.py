"""Set Scale in Blender (issue 12.3): a COLMAP capture whose world is 0.37x metric, with sparse points
that show no floor (so the import keeps its units), is made metric by typing the true distance between
two cameras or two picked points. Checked against the true room, whatever rotation the import applied:
distances between cameras, and between points and cameras, are rigid-motion invariant."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import scene_state
from fixtures_capture import colmap_image_entry, ring_poses, write_colmap_text, write_photo_folder

W, H = 64, 48
WORLD_SCALE = 0.37  # the COLMAP model's units per metre
TRUE_POSES = ring_poses(6, radius=2.0, height=1.5)
# Points on the walls above the cameras (a ceiling band): no floor, so the import cannot find the scale.
_angles = np.linspace(0.0, 2 * np.pi, 40, endpoint=False)
TRUE_POINTS = np.stack([3.0 * np.cos(_angles), 3.0 * np.sin(_angles), 2.0 + 0.5 * (np.arange(40) % 3)], axis=1)
POINT_RGB = np.stack([np.arange(40) * 6, 255 - np.arange(40) * 6, np.full(40, 30)], axis=1).astype(np.uint8)


@pytest.fixture
def scaled_colmap(tmp_path: Path) -> Path:
    names = [f"{i}.png" for i in range(len(TRUE_POSES))]
    write_photo_folder(tmp_path / "images", len(names), (W, H), names=names)
    poses = []
    for pose in TRUE_POSES:
        scaled = pose.copy()
        scaled[:3, 3] *= WORLD_SCALE
        poses.append(scaled)
    images = [colmap_image_entry(i + 1, pose, 1, name) for i, (pose, name) in enumerate(zip(poses, names))]
    model = write_colmap_text(tmp_path / "sparse" / "0", [(1, "PINHOLE", W, H, (60.0, 60.0, 32.0, 24.0))], images)
    lines = [f"{i + 1} {x!r} {y!r} {z!r} {r} {g} {b} 0.5"
             for i, ((x, y, z), (r, g, b)) in enumerate(zip((TRUE_POINTS * WORLD_SCALE).tolist(), POINT_RGB.tolist()))]
    (model / "points3D.txt").write_text("# 3D point list\n" + "\n".join(lines) + "\n")
    return tmp_path


def _cameras(bpy) -> list:
    return sorted((o for o in bpy.data.objects if o.type == "CAMERA" and "vortx_frame" in o), key=lambda o: o["vortx_frame"])


def _centres(cameras) -> np.ndarray:
    return np.array([np.array(o["vortx_pose"]).reshape(4, 4)[:3, 3] for o in cameras])


def _pairwise(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a[:, None] - b[None], axis=-1)


def _import(bpy, path: Path) -> None:
    assert bpy.ops.vortx.import_capture(filepath=str(path)) == {"FINISHED"}


def test_import_shows_the_colmap_points_as_a_coloured_point_cloud(blender, empty_scene, scaled_colmap: Path) -> None:
    import bpy

    _import(bpy, scaled_colmap)
    cloud = blender.vortx_blender.point_cloud.find_point_cloud(empty_scene)
    assert cloud is not None and cloud.name in bpy.data.collections["VoRTX Capture"].objects
    assert len(cloud.data.vertices) == len(TRUE_POINTS) and len(cloud.data.polygons) == 0
    assert cloud.modifiers[0].type == "NODES"  # Mesh to Points: drawn in Object Mode
    points, colours = blender.vortx_blender.point_cloud.scene_points(empty_scene)
    np.testing.assert_array_equal(colours, POINT_RGB)  # sRGB bytes survive the linear float attribute
    # Points and cameras moved together (same rigid motion, same units as the file).
    expected = _pairwise(TRUE_POINTS, np.array([p[:3, 3] for p in TRUE_POSES])) * WORLD_SCALE
    np.testing.assert_allclose(_pairwise(points, _centres(_cameras(bpy))), expected, atol=1e-5)
    assert empty_scene.vortx.scale_source == "unknown" and not empty_scene.vortx.poses_metric


def test_set_scale_between_two_cameras_makes_the_capture_metric(blender, empty_scene, scaled_colmap: Path) -> None:
    import bpy

    _import(bpy, scaled_colmap)
    # A result mesh standing in the capture's world scales with it.
    mesh = bpy.data.meshes.new("result")
    mesh.from_pydata([(0.1, 0.2, 0.3), (0.5, -0.4, 0.9)], [], [])
    result = bpy.data.objects.new("VoRTX Result", mesh)
    result["vortx_result"] = True
    result.location = (0.2, 0.0, 0.1)
    empty_scene.collection.objects.link(result)
    bpy.context.view_layer.update()
    before = [np.array(result.matrix_world) @ np.array([*v.co, 1.0]) for v in mesh.vertices]

    cameras = _cameras(bpy)
    true_distance = float(np.linalg.norm(TRUE_POSES[0][:3, 3] - TRUE_POSES[2][:3, 3]))
    for camera in cameras:
        camera.select_set(camera in (cameras[0], cameras[2]))
    assert bpy.ops.vortx.set_scale(distance=true_distance) == {"FINISHED"}

    centres = _centres(cameras)
    true_centres = np.array([p[:3, 3] for p in TRUE_POSES])
    np.testing.assert_allclose(_pairwise(centres, centres), _pairwise(true_centres, true_centres), rtol=0.01, atol=1e-6)
    # The Blender cameras moved with their stored poses; the point cloud with the cameras.
    for camera, centre in zip(cameras, centres):
        np.testing.assert_allclose(np.array(camera.matrix_world)[:3, 3], centre, atol=1e-5)
    points, _ = blender.vortx_blender.point_cloud.scene_points(empty_scene)
    np.testing.assert_allclose(_pairwise(points, centres), _pairwise(TRUE_POINTS, true_centres), rtol=0.01)
    factor = 1.0 / WORLD_SCALE
    bpy.context.view_layer.update()
    after = [np.array(result.matrix_world) @ np.array([*v.co, 1.0]) for v in mesh.vertices]
    np.testing.assert_allclose(np.array(after)[:, :3], np.array(before)[:, :3] * factor, rtol=1e-4)
    assert np.allclose(np.array(result.matrix_world)[:3, :3], np.eye(3))  # no object scale added

    settings = empty_scene.vortx
    assert settings.scale_source == "known distance" and settings.poses_metric
    assert "scaled by a known distance" in settings.pose_status
    assert "known distance" in settings.scale_description and f"{true_distance:g} m" in settings.scale_description
    # The next reconstruction takes the cameras as they are: no second rescale from the camera height.
    capture = blender.vortx_blender.reconstruct.scene_capture(empty_scene)
    np.testing.assert_allclose(np.array([f.pose[:3, 3] for f in capture.frames]), centres, atol=1e-9)


def test_set_scale_between_two_picked_points_in_edit_mode(blender, empty_scene, scaled_colmap: Path) -> None:
    import bpy

    _import(bpy, scaled_colmap)
    cloud = blender.vortx_blender.point_cloud.find_point_cloud(empty_scene)
    for obj in bpy.data.objects:
        obj.select_set(False)
    bpy.context.view_layer.objects.active = cloud
    cloud.select_set(True)
    for vertex in cloud.data.vertices:
        vertex.select = vertex.index in (3, 17)
    bpy.ops.object.mode_set(mode="EDIT")
    true_distance = float(np.linalg.norm(TRUE_POINTS[3] - TRUE_POINTS[17]))
    try:
        assert bpy.ops.vortx.set_scale(distance=true_distance) == {"FINISHED"}
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
    points, _ = blender.vortx_blender.point_cloud.scene_points(empty_scene)
    assert np.linalg.norm(points[3] - points[17]) == pytest.approx(true_distance, rel=0.01)
    centres = _centres(_cameras(bpy))
    true_centres = np.array([p[:3, 3] for p in TRUE_POSES])
    np.testing.assert_allclose(_pairwise(centres, centres), _pairwise(true_centres, true_centres), rtol=0.01, atol=1e-6)


def test_refused_set_scale_changes_nothing_and_the_operator_is_undoable(blender, empty_scene, scaled_colmap: Path) -> None:
    import bpy

    assert "UNDO" in bpy.types.VORTX_OT_set_scale.bl_options
    _import(bpy, scaled_colmap)
    cameras = _cameras(bpy)
    points_before, _ = blender.vortx_blender.point_cloud.scene_points(empty_scene)
    state = scene_state(empty_scene)

    def refused(distance: float, selected: list, match: str) -> None:
        for camera in cameras:
            camera.select_set(camera in selected)
        with pytest.raises(RuntimeError, match=match):
            bpy.ops.vortx.set_scale(distance=distance)
        points, _ = blender.vortx_blender.point_cloud.scene_points(empty_scene)
        np.testing.assert_array_equal(points, points_before)
        assert scene_state(empty_scene) == state

    refused(2.0, cameras[:1], "1 capture cameras are selected: select exactly two")
    refused(2.0, cameras[:3], "3 capture cameras are selected")
    refused(0.0, cameras[:2], "known distance must be a positive number of metres, got 0")
    refused(-1.5, cameras[:2], "must be a positive number")
