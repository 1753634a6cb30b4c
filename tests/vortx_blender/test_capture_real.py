"""Import Capture and Estimate Poses through bpy.ops with the engine's real loaders and real SfM.

Captures are written here with plain numpy/OpenCV (not with engine code), so what Blender ends up
with is compared against values computed independently.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import ExifTags, Image

from conftest import SHARED_DATA, look_at_pose, scene_state
from fixtures_raycast_room import render_room, wall_textures

OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def _write_image(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])


def _noise_image(width: int, height: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


def _write_transforms(folder: Path, poses_cv: list[np.ndarray], fx: float, fy: float, cx: float, cy: float, size=(64, 48),
                      metric: bool = False) -> Path:
    """instant-ngp transforms.json: transform_matrix is camera-to-world in OpenGL camera axes.
    `metric` writes our tools' `"metric": true` (import then keeps the poses as they are)."""
    frames = []
    for i, pose in enumerate(poses_cv):
        _write_image(folder / "images" / f"{i:03d}.jpg", _noise_image(*size, seed=i))
        frames.append({"file_path": f"images/{i:03d}.jpg", "transform_matrix": (pose @ OPENGL_FROM_OPENCV).tolist()})
    path = folder / "transforms.json"
    top = {"metric": True} if metric else {}
    path.write_text(json.dumps({"fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": size[0], "h": size[1], "frames": frames, **top}))
    return path


def _ring(count: int) -> list[np.ndarray]:
    return [look_at_pose([2.0 * np.cos(a), 2.0 * np.sin(a), 1.4], [0.1, -0.2, 1.0]) for a in np.linspace(0, 2 * np.pi, count, endpoint=False)]


def _capture_cameras(bpy) -> list:
    return sorted((o for o in bpy.data.objects if o.type == "CAMERA" and "vortx_frame" in o), key=lambda o: o["vortx_frame"])


def test_transforms_json_cameras_match_the_file(blender, empty_scene, tmp_path: Path) -> None:
    import bpy
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    poses = _ring(5)
    fx, fy, cx, cy = 70.0, 64.0, 30.5, 25.0
    path = _write_transforms(tmp_path / "cap", poses, fx, fy, cx, cy, metric=True)
    assert bpy.ops.vortx.import_capture(filepath=str(path)) == {"FINISHED"}
    settings = empty_scene.vortx
    assert (settings.capture_format, settings.frame_count, settings.posed_frame_count) == ("transforms", 5, 5)
    assert (settings.resolution_x, settings.resolution_y) == (64, 48)
    cameras = _capture_cameras(bpy)
    assert len(cameras) == 5
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    for obj, pose in zip(cameras, poses):
        # Blender camera axes are OpenGL camera axes: the file's matrix is the camera's matrix_world.
        np.testing.assert_allclose(np.array(obj.matrix_world), pose @ OPENGL_FROM_OPENCV, atol=1e-5)
        point = pose[:3, :3] @ np.array([0.3, -0.2, 2.5]) + pose[:3, 3]
        u, v, _ = world_to_camera_view(empty_scene, obj, Vector(point.tolist()))
        expected = K @ np.array([0.3, -0.2, 2.5])
        assert np.allclose([u * 64, (1 - v) * 48], expected[:2] / expected[2], atol=0.01)


def test_frames_with_nan_matrix_are_skipped_with_a_warning(blender, empty_scene, tmp_path: Path, capfd) -> None:
    import bpy

    poses = _ring(4)
    path = _write_transforms(tmp_path / "cap", poses, 70.0, 70.0, 32.0, 24.0)
    data = json.loads(path.read_text())
    data["frames"][2]["transform_matrix"][0][3] = float("nan")
    path.write_text(json.dumps(data))  # json writes NaN, which Python readers accept
    assert bpy.ops.vortx.import_capture(filepath=str(path)) == {"FINISHED"}
    assert [o["vortx_frame"] for o in _capture_cameras(bpy)] == [0, 1, 2]
    assert [Path(o["vortx_image"]).name for o in _capture_cameras(bpy)] == ["000.jpg", "001.jpg", "003.jpg"]
    assert "002.jpg" in capfd.readouterr().out  # the operator's WARNING report names the skipped frame


def _previous_import(bpy, tmp_path: Path) -> None:
    path = _write_transforms(tmp_path / "good", _ring(3), 70.0, 70.0, 32.0, 24.0)
    assert bpy.ops.vortx.import_capture(filepath=str(path)) == {"FINISHED"}


def _all_nan(tmp_path: Path) -> tuple[Path, str]:
    path = _write_transforms(tmp_path / "bad", _ring(3), 70.0, 70.0, 32.0, 24.0)
    data = json.loads(path.read_text())
    for frame in data["frames"]:
        frame["transform_matrix"][1][1] = float("nan")
    path.write_text(json.dumps(data))
    return path, "no usable frame"


def _empty_folder(tmp_path: Path) -> tuple[Path, str]:
    folder = tmp_path / "empty"
    folder.mkdir()
    return folder, "empty"


def _corrupt_photo(tmp_path: Path) -> tuple[Path, str]:
    """One good photo and one truncated: a bad photo is skipped, and one photo left is too few."""
    folder = tmp_path / "photos"
    for i in (1, 2):
        _write_image(folder / f"{i:03d}.jpg", _noise_image(64, 48, seed=10 + i))
    data = (folder / "002.jpg").read_bytes()
    (folder / "002.jpg").write_bytes(data[: len(data) // 3])  # truncated copy
    return folder, "002.jpg"


@pytest.mark.parametrize("make_failure", [_all_nan, _empty_folder, _corrupt_photo], ids=["NaN poses", "empty folder", "corrupt photo"])
def test_failed_import_leaves_scene_unchanged(blender, empty_scene, tmp_path: Path, make_failure) -> None:
    import bpy

    _previous_import(bpy, tmp_path)
    before = scene_state(empty_scene)
    path, message = make_failure(tmp_path)
    with pytest.raises(RuntimeError) as info:
        bpy.ops.vortx.import_capture(filepath=str(path))
    assert message in str(info.value)
    assert scene_state(empty_scene) == before


# --- real structure from motion on a small synthetic room ------------------------------------------

@pytest.mark.slow
def test_estimate_poses_headless_on_synthetic_room(blender, empty_scene, tmp_path: Path) -> None:
    import bpy

    poses_engine = importlib.import_module(f"{blender.__name__}.engine.poses")
    room = np.array([4.0, 4.0, 2.5])
    size = (320, 240)
    # Photos carry an EXIF 35 mm-equivalent focal length, as phone photos do; the loader turns it
    # into K = f35 * diagonal / 43.27 mm (about 60 deg wide here). Without that prior, SfM on ten
    # views of a box sometimes settles on a wrong focal length and a bent trajectory.
    f35 = 30
    f = f35 * np.hypot(*size) / np.hypot(36.0, 24.0)
    K = np.array([[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1]])
    # Cameras 1.5 m up on a 1.2 m circle, each looking across the room at a far corner region:
    # two walls in view gives SfM the parallax a single flat wall would not.
    truth = []
    for a in np.linspace(0, 2 * np.pi, 10, endpoint=False):
        eye = np.array([2.0 + 1.2 * np.cos(a), 2.0 + 1.2 * np.sin(a), 1.5])
        truth.append(look_at_pose(eye, [2.0 - 1.5 * np.cos(a - 0.5), 2.0 - 1.5 * np.sin(a - 0.5), 1.3]))
    walls = wall_textures(seed=0)
    photos = tmp_path / "room"
    photos.mkdir()
    for i, pose in enumerate(truth):
        exif = Image.Exif()
        exif.get_ifd(ExifTags.IFD.Exif)[0xA405] = f35  # FocalLengthIn35mmFilm
        Image.fromarray(render_room(K, pose, size, room, walls)).save(photos / f"{i:03d}.jpg", exif=exif, quality=95)

    assert bpy.ops.vortx.import_capture(filepath=str(photos)) == {"FINISHED"}
    assert empty_scene.vortx.pose_status == "No poses: run Estimate Poses"
    assert _capture_cameras(bpy) == []

    assert bpy.ops.vortx.estimate_poses() == {"FINISHED"}
    settings = empty_scene.vortx
    cameras = _capture_cameras(bpy)
    assert settings.posed_frame_count == len(cameras) >= 8
    assert settings.pose_status.startswith(f"{len(cameras)} of 10 posed by SfM")
    # The Blender cameras reproduce the true trajectory up to a similarity.
    estimated = [np.array(o.matrix_world) @ np.diag([1.0, -1.0, -1.0, 1.0]) for o in cameras]
    errors = poses_engine.pose_errors(estimated, [truth[o["vortx_frame"]] for o in cameras])
    assert errors["rotation_deg_max"] < 1.0, errors
    # Gravity alignment put the cameras upright: their up vector (-y in OpenCV axes) is close to +Z.
    ups = np.array([-p[:3, 1] for p in estimated])
    assert np.all(ups[:, 2] > 0.9), ups


def test_real_fox_capture(blender, empty_scene) -> None:
    """The instant-ngp fox photos (portrait phone photos, some frames without photos)."""
    import bpy

    folder = SHARED_DATA / "fox"
    if not (folder / "transforms.json").is_file():
        pytest.skip(f"real test data not available: {folder} is missing (only present beside the team's checkout)")
    assert bpy.ops.vortx.import_capture(filepath=str(folder / "transforms.json")) == {"FINISHED"}
    settings = empty_scene.vortx
    cameras = _capture_cameras(bpy)
    assert settings.frame_count == settings.posed_frame_count == len(cameras) == 50
    assert (settings.resolution_x, settings.resolution_y) == (1080, 1920)
    assert (empty_scene.render.resolution_x, empty_scene.render.resolution_y) == (1080, 1920)
    assert all(c.data.sensor_fit == "VERTICAL" for c in cameras)


def test_a_zipped_phone_export_lands_with_arkit_poses_and_its_depth_as_points(blender, empty_scene, tmp_path: Path) -> None:
    """Import Capture on a 3D Scanner App export's .zip: the cameras at the ARKit poses turned Z up,
    the Poses line naming ARKit, metric, and the LiDAR depth as the scene's point cloud."""
    import zipfile

    import bpy

    from fixtures_phone import walk, write_export
    scene_points = importlib.import_module(f"{blender.__name__}.vortx_blender.point_cloud").scene_points

    folder = write_export(tmp_path / "scan", walk(5))
    archive = tmp_path / "scan.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for path in sorted(folder.iterdir()):
            zf.write(path, f"scan/{path.name}")
    assert bpy.ops.vortx.import_capture(filepath=str(archive)) == {"FINISHED"}
    settings = empty_scene.vortx
    assert (settings.capture_format, settings.frame_count, settings.posed_frame_count) == ("3dscannerapp", 5, 5)
    assert settings.poses_metric and settings.pose_source == "ARKit (3D Scanner App)"
    assert settings.pose_status == "All 5 posed (ARKit (3D Scanner App)), metric"
    cameras = _capture_cameras(bpy)
    assert len(cameras) == 5
    for obj in cameras:  # the phone was held upright: Blender's camera up (its local +y) is world +Z
        np.testing.assert_allclose(np.array(obj.matrix_world)[:3, 1], [0.0, 0.0, 1.0], atol=1e-5)
    points, _ = scene_points(empty_scene)
    # walk()'s depth: frame i sees a wall 1 + 0.1 i m ahead, confident on the left half of each map.
    assert points is not None and len(points) > 0
    for obj, depth_m in zip(cameras, (1.0, 1.1, 1.2, 1.3, 1.4)):
        camera = np.array(obj.matrix_world)
        ahead = (points - camera[:3, 3]) @ -camera[:3, 2]  # Blender cameras look down their local -z
        assert np.any(np.abs(ahead - depth_m) < 1e-3)
    # Reconstruct rebuilds the capture from the cameras: each frame still carries its LiDAR map, so the
    # run uses it (its depth maps from the sensor, no stereo), as `engine reconstruct` does.
    from engine.capture.sensor_depth import read_sensor_depth
    rebuilt = importlib.import_module(f"{blender.__name__}.vortx_blender.cameras").posed_capture_from_scene(empty_scene)
    assert all(f.sensor_depth is not None for f in rebuilt.frames)
    for frame, depth_m in zip(rebuilt.frames, (1.0, 1.1, 1.2, 1.3, 1.4)):
        depth, confidence = read_sensor_depth(frame.sensor_depth)
        assert confidence is not None and np.allclose(depth[confidence >= 2], depth_m, atol=1e-3)


def test_the_real_corridor_export_imports_with_its_cameras_and_depth_points(blender, empty_scene) -> None:
    """The 3D Scanner App corridor sample as it comes (fetched outside the repository), through Import
    Capture: 146 cameras, ARKit metric poses, the LiDAR's points."""
    import bpy

    from fixtures_phone import CORRIDOR
    if not CORRIDOR.is_dir():
        pytest.skip(f"the 3D Scanner App corridor sample is not at {CORRIDOR} (fetch github "
                    "PyojinKim/3dScannerApp_samples, folder rgbd_dataset_renaissance_03_corridor01/All_Data, "
                    "or set VORTX_CORRIDOR)")
    scene_points = importlib.import_module(f"{blender.__name__}.vortx_blender.point_cloud").scene_points
    assert bpy.ops.vortx.import_capture(filepath=str(CORRIDOR)) == {"FINISHED"}
    settings = empty_scene.vortx
    assert (settings.capture_format, settings.frame_count, settings.posed_frame_count) == ("3dscannerapp", 146, 146)
    assert settings.poses_metric and settings.pose_source.startswith("ARKit (3D Scanner App)")
    assert len(_capture_cameras(bpy)) == 146
    points, colours = scene_points(empty_scene)
    assert points is not None and len(points) > 50_000
    # The corridor's floor: the lowest dense band of LiDAR points lies 1.2-1.7 m below the cameras.
    camera_z = np.median([np.array(o.matrix_world)[2, 3] for o in _capture_cameras(bpy)])
    floor_z = np.percentile(points[:, 2], 5)
    assert 1.2 < camera_z - floor_z < 1.7


def test_arkitscenes_video_folder_imports_upright_and_metric(blender, empty_scene, tmp_path: Path) -> None:
    # An iPad's landscape photos of a portrait capture: the cameras come in upright, the photo portrait.
    import bpy

    from fixtures_arkitscenes import H, W, capture_poses, write_arkitscenes

    poses = capture_poses()
    folder = write_arkitscenes(tmp_path / "40777060", poses, [10.0, 10.1, 10.2, 10.3])
    assert bpy.ops.vortx.import_capture(filepath=str(folder)) == {"FINISHED"}
    settings = empty_scene.vortx
    assert (settings.capture_format, settings.frame_count, settings.posed_frame_count) == ("arkitscenes", 4, 4)
    assert (settings.resolution_x, settings.resolution_y) == (H, W)
    cameras = _capture_cameras(bpy)
    for obj, given in zip(cameras, poses):
        matrix = np.array(obj.matrix_world)
        assert matrix[2, 1] > 0.9, "a Blender camera's up (local +Y) points up the world"
        np.testing.assert_allclose(matrix[:3, 3], given[:3, 3], atol=1e-5)  # metres, where the iPad was
