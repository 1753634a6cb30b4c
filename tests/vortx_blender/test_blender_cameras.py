"""Capture cameras in Blender: exact projection (the issue's acceptance test), replacement, validation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import look_at_pose, scene_state


def _capture(blender, root: Path, width: int, height: int, K: np.ndarray, poses: list[np.ndarray | None], fmt: str = "transforms"):
    from_engine = blender.engine.capture
    frames = [
        from_engine.Frame(image_path=root / f"frame_{i:03d}.jpg", width=width, height=height, K=K.copy(), pose=None if p is None else p.copy())
        for i, p in enumerate(poses)
    ]
    return from_engine.Capture(root=root, format=fmt, frames=frames)


def _orbit_poses(count: int, seed: int) -> list[np.ndarray]:
    """Cameras around a room at varied heights, looking at varied points (non-trivial rotations)."""
    rng = np.random.default_rng(seed)
    poses = []
    for i in range(count):
        angle = 2 * np.pi * i / count
        eye = np.array([2.5 * np.cos(angle), 2.0 * np.sin(angle), 1.2 + 0.6 * rng.random()])
        target = rng.uniform([-0.5, -0.5, 0.3], [0.5, 0.5, 1.5])
        poses.append(look_at_pose(eye, target))
    return poses


def _visible_points(K: np.ndarray, pose: np.ndarray, width: int, height: int, count: int, rng) -> np.ndarray:
    """World points that project inside the image, at 0.5-6 m depth (the range a room spans)."""
    pixels = rng.uniform([0, 0], [width, height], size=(count, 2))
    depth = rng.uniform(0.5, 6.0, size=count)
    rays = np.linalg.inv(K) @ np.vstack([pixels.T, np.ones(count)])
    cam = rays * depth
    return (pose[:3, :3] @ cam).T + pose[:3, 3]


def _engine_projection(K: np.ndarray, pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    world_to_cam = np.linalg.inv(pose)
    cam = points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
    uvw = cam @ K.T
    return uvw[:, :2] / uvw[:, 2:3]


def _blender_projection(scene, camera, points: np.ndarray, width: int, height: int) -> np.ndarray:
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    out = []
    for p in points:
        u, v, _ = world_to_camera_view(scene, camera, Vector(p.tolist()))
        out.append((u * width, (1.0 - v) * height))
    return np.array(out)


CASES = {
    # name: (width, height, fx, fy, cx, cy)
    "landscape": (640, 480, 500.0, 500.0, 331.7, 236.4),
    "portrait": (1080, 1920, 1450.0, 1450.0, 530.2, 968.9),
    "fx>fy off-centre": (640, 480, 610.0, 540.0, 285.0, 262.0),
    "fy>fx off-centre portrait": (480, 640, 505.0, 575.0, 251.0, 301.5),
    "near-square, fx>fy flips the fitted side": (500, 480, 700.0, 600.0, 240.0, 250.0),
}


@pytest.mark.parametrize("case", list(CASES))
def test_blender_camera_projects_like_engine_pinhole(blender, empty_scene, tmp_path: Path, case: str) -> None:
    width, height, fx, fy, cx, cy = CASES[case]
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    capture = _capture(blender, tmp_path, width, height, K, _orbit_poses(4, seed=1))
    cameras, warnings = blender.vortx_blender.cameras.build_capture_cameras(empty_scene, capture)
    assert len(cameras) == 4 and warnings == []
    rng = np.random.default_rng(7)
    for obj, frame in zip(cameras, capture.frames):
        points = _visible_points(K, frame.pose, width, height, 40, rng)
        expected = _engine_projection(K, frame.pose, points)
        got = _blender_projection(empty_scene, obj, points, width, height)
        error = np.abs(got - expected).max()
        # Acceptance is 0.5 px; the conversion is exact up to Blender's float32 matrices.
        assert error < 0.01, f"{case}: {obj.name} is off by {error:.4f} px"


def test_render_settings_follow_capture(blender, empty_scene, tmp_path: Path) -> None:
    K = np.array([[600.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    capture = _capture(blender, tmp_path, 640, 480, K, _orbit_poses(2, seed=2))
    blender.vortx_blender.cameras.build_capture_cameras(empty_scene, capture)
    render = empty_scene.render
    assert (render.resolution_x, render.resolution_y, render.resolution_percentage) == (640, 480, 100)
    assert render.pixel_aspect_x == pytest.approx(1.0)
    assert render.pixel_aspect_y == pytest.approx(1.2)


def test_unposed_frames_get_no_camera(blender, empty_scene, tmp_path: Path) -> None:
    K = np.diag([400.0, 400.0, 1.0])
    K[:2, 2] = (160, 120)
    poses = _orbit_poses(3, seed=3)
    capture = _capture(blender, tmp_path, 320, 240, K, [poses[0], None, poses[2]])
    cameras, _ = blender.vortx_blender.cameras.build_capture_cameras(empty_scene, capture)
    assert [obj["vortx_frame"] for obj in cameras] == [0, 2]
    assert all(obj.type == "CAMERA" for obj in cameras)
    assert {c.name for c in cameras[0].users_collection} == {"VoRTX Capture"}


def test_reimport_replaces_only_our_cameras(blender, empty_scene, tmp_path: Path) -> None:
    import bpy

    cameras_module = blender.vortx_blender.cameras
    # User content: a camera outside our collection (the active one) and a mesh the user put inside it.
    user_cam = bpy.data.objects.new("User Camera", bpy.data.cameras.new("User Camera"))
    empty_scene.collection.objects.link(user_cam)
    empty_scene.camera = user_cam
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])

    cameras_module.build_capture_cameras(empty_scene, _capture(blender, tmp_path, 640, 480, K, _orbit_poses(5, seed=4)))
    collection = blender.vortx_blender.scene_objects.find_capture_collection(empty_scene)
    guest = bpy.data.objects.new("User Mesh", bpy.data.meshes.new("User Mesh"))
    collection.objects.link(guest)
    collection.name = "My renamed capture"  # found by its tag, not its name

    second = _capture(blender, tmp_path, 640, 480, K, _orbit_poses(3, seed=5))
    cameras, _ = cameras_module.build_capture_cameras(empty_scene, second)
    assert len(cameras) == 3
    assert blender.vortx_blender.scene_objects.find_capture_collection(empty_scene) == collection
    assert sorted(o.name for o in collection.objects) == sorted([c.name for c in cameras] + ["User Mesh"])
    assert not any(".0" in o.name for o in cameras), "old cameras were left behind"
    assert len([c for c in bpy.data.cameras if c.users == 0]) == 0, "camera data of removed cameras leaked"
    assert empty_scene.camera == user_cam
    assert set(bpy.data.objects.keys()) == {"User Camera", "User Mesh"} | {c.name for c in cameras}
    np.testing.assert_allclose(np.array(cameras[1].matrix_world), second.frames[1].pose @ np.diag([1, -1, -1, 1]), atol=1e-6)


@pytest.mark.parametrize(
    "breakage",
    ["nan pose", "scaled rotation", "missing K", "zero focal", "mixed sizes"],
)
def test_invalid_frames_raise_and_change_nothing(blender, empty_scene, tmp_path: Path, breakage: str) -> None:
    cameras_module = blender.vortx_blender.cameras
    errors = blender.engine.errors
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    cameras_module.build_capture_cameras(empty_scene, _capture(blender, tmp_path, 640, 480, K, _orbit_poses(3, seed=6)))
    before = scene_state(empty_scene)

    capture = _capture(blender, tmp_path, 640, 480, K, _orbit_poses(4, seed=7))
    bad = capture.frames[2]
    if breakage == "nan pose":
        bad.pose[0, 3] = np.nan
    elif breakage == "scaled rotation":
        bad.pose[:3, :3] *= 2.0
    elif breakage == "missing K":
        bad.K = None
    elif breakage == "zero focal":
        bad.K[1, 1] = 0.0
    elif breakage == "mixed sizes":
        bad.width = 320
    with pytest.raises(errors.VortxError) as info:
        cameras_module.build_capture_cameras(empty_scene, capture)
    if breakage != "mixed sizes":
        assert bad.name in str(info.value)
    assert scene_state(empty_scene) == before


def test_mixed_focal_ratios_warn(blender, empty_scene, tmp_path: Path) -> None:
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    capture = _capture(blender, tmp_path, 640, 480, K, _orbit_poses(3, seed=8))
    capture.frames[1].K[0, 0] = 520.0
    _, warnings = blender.vortx_blender.cameras.build_capture_cameras(empty_scene, capture)
    assert len(warnings) == 1 and "fx/fy" in warnings[0]


def test_posed_capture_survives_save_and_reload(blender, empty_scene, tmp_path: Path) -> None:
    import bpy

    K = np.array([[512.3456789, 0, 319.87654321], [0, 498.7654321, 241.123456789], [0, 0, 1]])
    capture = _capture(blender, tmp_path, 640, 480, K, _orbit_poses(4, seed=9))
    capture.frames[3].pose[:3, 3] += 1e-9  # float64 detail a float32 matrix_world could not hold
    blender.vortx_blender.capture.apply_capture(empty_scene, capture, tmp_path)
    path = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    assert blender.vortx_blender.cameras.posed_capture_from_scene(bpy.context.scene) is None
    bpy.ops.wm.open_mainfile(filepath=str(path))

    restored = blender.vortx_blender.cameras.posed_capture_from_scene(bpy.context.scene)
    assert restored is not None
    assert restored.format == "transforms" and restored.root == tmp_path
    assert [f.image_path for f in restored.frames] == [f.image_path for f in capture.frames]
    for got, want in zip(restored.frames, capture.frames):
        assert (got.width, got.height) == (want.width, want.height)
        np.testing.assert_array_equal(got.K, want.K)
        np.testing.assert_array_equal(got.pose, want.pose)
