"""COLMAP sparse models: text and binary, layouts, camera models, undistortion, bad poses."""

from __future__ import annotations

import numpy as np
import pytest

from engine.capture import load_capture, load_image
from engine.capture.colmap_model import read_model
from engine.capture.geometry import quaternion_to_rotation
from engine.errors import CaptureError
from fixtures_capture import (blob_centroid, blob_image, colmap_image_entry, distort_normalized, project,
                              ring_poses, write_colmap_binary, write_colmap_text, write_image, write_photo_folder)

W, H = 64, 48
POINT = np.array([0.3, -0.2, 1.1])  # a world point every ring camera sees


def _project_world(K_params: tuple[float, float, float, float], pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    fx, fy, cx, cy = K_params
    return project(np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), pose, point)


def _model(poses, names, model="PINHOLE", params=(70.0, 72.0, 31.0, 25.0)):
    cameras = [(1, model, W, H, params)]
    images = [colmap_image_entry(10 + i, pose, 1, name) for i, (pose, name) in enumerate(zip(poses, names))]
    return cameras, images


@pytest.mark.parametrize("writer", [write_colmap_text, write_colmap_binary])
def test_poses_and_K_round_trip(tmp_path, writer):
    poses = ring_poses(5)
    names = [f"img{i}.png" for i in range(5)]
    write_photo_folder(tmp_path / "images", 5, (W, H), names=names)
    # images listed out of order in the file: frames must come out in natural name order
    cameras, images = _model(poses, names)
    writer(tmp_path / "sparse" / "0", cameras, images[::-1])

    capture = load_capture(tmp_path)

    assert capture.format == "colmap" and capture.metric is False and capture.warnings == []
    assert [f.name for f in capture.frames] == names
    for frame, pose in zip(capture.frames, poses):
        np.testing.assert_allclose(frame.K, [[70, 0, 31], [0, 72, 25], [0, 0, 1]])
        np.testing.assert_allclose(frame.pose, pose, atol=1e-9)
        np.testing.assert_allclose(project(frame.K, frame.pose, POINT), _project_world((70, 72, 31, 25), pose, POINT),
                                   atol=1e-6)


def test_reader_matches_pycolmap_written_models(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="SIMPLE_RADIAL", width=W, height=H,
                                                    params=[60.0, 32.0, 24.0, 0.01], camera_id=3))
    poses = ring_poses(3)
    for i, pose in enumerate(poses):
        world_to_camera = np.linalg.inv(pose)
        rigid = pycolmap.Rigid3d(pycolmap.Rotation3d(world_to_camera[:3, :3]), world_to_camera[:3, 3])
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"v{i}.jpg", camera_id=3, image_id=i + 1), rigid)
    (tmp_path / "text").mkdir()
    (tmp_path / "bin").mkdir()
    rec.write_text(str(tmp_path / "text"))
    rec.write_binary(str(tmp_path / "bin"))
    for folder, kind in ((tmp_path / "text", "text"), (tmp_path / "bin", "binary")):
        model = read_model(folder)
        assert model.kind == kind
        camera = model.cameras[3]
        assert (camera.model, camera.width, camera.height) == ("SIMPLE_RADIAL", W, H)
        np.testing.assert_allclose(camera.params, [60.0, 32.0, 24.0, 0.01])
        assert [im.name for im in model.images] == ["v0.jpg", "v1.jpg", "v2.jpg"]
        for image, pose in zip(model.images, poses):
            expected = rec.images[image.image_id].cam_from_world().matrix()
            np.testing.assert_allclose(quaternion_to_rotation(image.qvec), expected[:, :3], atol=1e-12)
            np.testing.assert_allclose(image.tvec, expected[:, 3], atol=1e-12)


def test_simple_pinhole_model_in_sparse_folder_with_unregistered_photo(tmp_path):
    poses = ring_poses(3)
    names = ["a.png", "b.png", "c.png"]
    write_photo_folder(tmp_path / "images", 4, (W, H), names=names + ["extra.png"])
    cameras, images = _model(poses, names, "SIMPLE_PINHOLE", (65.0, 32.0, 24.0))
    write_colmap_binary(tmp_path / "sparse", cameras, images)
    capture = load_capture(tmp_path)
    np.testing.assert_allclose(capture.frames[0].K, [[65, 0, 32], [0, 65, 24], [0, 0, 1]])
    assert len(capture.frames) == 3
    assert any("extra.png" in w and "not registered" in w for w in capture.warnings)


def test_model_in_folder_itself_and_largest_of_several_models(tmp_path):
    poses = ring_poses(4)
    names = [f"{i}.png" for i in range(4)]
    write_photo_folder(tmp_path / "images", 4, (W, H), names=names)
    cameras, images = _model(poses, names)
    write_colmap_text(tmp_path / "sparse" / "0", cameras, images[:2])
    write_colmap_text(tmp_path / "sparse" / "1", cameras, images)
    capture = load_capture(tmp_path)
    assert len(capture.frames) == 4
    assert any("several COLMAP models" in w and str(tmp_path / "sparse" / "0") in w for w in capture.warnings)

    # a model directly in the chosen folder, images/ beside it
    flat = tmp_path / "flat"
    write_photo_folder(flat / "images", 4, (W, H), names=names)
    write_colmap_text(flat, cameras, images)
    assert load_capture(flat).format == "colmap" and len(load_capture(flat).frames) == 4
    # and the user may point at sparse/0 itself
    assert len(load_capture(tmp_path / "sparse" / "1").frames) == 4


def test_opencv_distortion_is_undistorted_exactly(tmp_path):
    """Blobs drawn where a distorted camera sees known 3D points land, after undistortion, where
    the returned pinhole K and pose project those points."""
    width, height = 160, 120
    fx, fy, cx, cy = 100.0, 102.0, 81.0, 59.0
    k1, k2, p1, p2 = -0.18, 0.03, 0.002, -0.001
    poses = ring_poses(2)
    normalized = np.array([[0.0, 0.0], [-0.6, -0.45], [0.65, 0.4], [0.55, -0.42], [-0.5, 0.35]])
    names = ["d0.png", "d1.png"]
    world_points = []
    for i, (pose, name) in enumerate(zip(poses, names)):
        normalized = normalized + 0.03 * i  # different photos (identical ones would be dropped as duplicates)
        distorted = distort_normalized(normalized, k1, k2, p1, p2) * [fx, fy] + [cx, cy]
        write_image(tmp_path / "images" / name, blob_image(width, height, distorted))
        camera_points = np.hstack([normalized, np.ones((len(normalized), 1))]) * 2.0  # 2 m in front
        world_points.append(camera_points @ pose[:3, :3].T + pose[:3, 3])
    cameras = [(1, "OPENCV", width, height, (fx, fy, cx, cy, k1, k2, p1, p2))]
    images = [colmap_image_entry(i + 1, pose, 1, name) for i, (pose, name) in enumerate(zip(poses, names))]
    write_colmap_binary(tmp_path / "sparse" / "0", cameras, images)

    capture = load_capture(tmp_path, cache_dir=tmp_path / "cache")

    assert any("undistorted" in note for note in capture.notes)
    for frame, points in zip(capture.frames, world_points):
        assert frame.image_path.parent.parent == tmp_path / "cache"  # not the original photo
        undistorted = load_image(frame.image_path)
        assert undistorted.shape == (height, width, 3)
        for point in points:
            expected = project(frame.K, frame.pose, point)
            found = blob_centroid(undistorted, expected)
            assert np.linalg.norm(found - expected) < 0.15, (frame.name, expected, found)
    # Loading again reuses the cache (same files, not rewritten).
    stamp = capture.frames[0].image_path.stat().st_mtime_ns
    again = load_capture(tmp_path, cache_dir=tmp_path / "cache")
    assert again.frames[0].image_path.stat().st_mtime_ns == stamp
    np.testing.assert_allclose(again.frames[0].K, capture.frames[0].K)


def test_distortion_kept_with_warning_when_undistort_is_off(tmp_path):
    names = ["a.png", "b.png"]
    write_photo_folder(tmp_path / "images", 2, (W, H), names=names)
    cameras, images = _model(ring_poses(2), names, "RADIAL", (60.0, 32.0, 24.0, 0.05, -0.01))
    write_colmap_text(tmp_path / "sparse" / "0", cameras, images)
    capture = load_capture(tmp_path, undistort=False)
    assert capture.frames[0].image_path == tmp_path / "images" / "a.png"
    np.testing.assert_allclose(capture.frames[0].K, [[60, 0, 32], [0, 60, 24], [0, 0, 1]])
    assert any("undistort=False" in w for w in capture.warnings)


@pytest.mark.parametrize("writer,model,params,file_name", [
    (write_colmap_text, "FULL_OPENCV", (60.0, 60.0, 32.0, 24.0) + (0.0,) * 8, "cameras.txt"),
    (write_colmap_binary, "OPENCV_FISHEYE", (60.0, 60.0, 32.0, 24.0, 0.1, 0.0, 0.0, 0.0), "cameras.bin"),
    (write_colmap_binary, "FISHEYE", (60.0, 60.0, 32.0, 24.0), "cameras.bin"),
])
def test_unsupported_camera_model_is_refused_by_name(tmp_path, writer, model, params, file_name):
    names = ["a.png", "b.png"]
    write_photo_folder(tmp_path / "images", 2, (W, H), names=names)
    cameras, images = _model(ring_poses(2), names, model, params)
    writer(tmp_path / "sparse" / "0", cameras, images)
    with pytest.raises(CaptureError) as error:
        load_capture(tmp_path)
    message = str(error.value)
    assert model in message and file_name in message and "image_undistorter" in message


def test_nan_pose_and_missing_photo_are_skipped_with_warnings(tmp_path):
    names = ["a.png", "b.png", "c.png", "gone.png"]
    write_photo_folder(tmp_path / "images", 3, (W, H), names=names[:3])
    cameras, images = _model(ring_poses(4), names)
    images[1] = (images[1][0], np.array([np.nan, 0, 0, 0]), images[1][2], 1, "b.png")
    write_colmap_text(tmp_path / "sparse" / "0", cameras, images)
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == ["a.png", "c.png"]
    assert any("b.png" in w and "non-finite" in w for w in capture.warnings)
    assert any("gone.png" in w and "missing" in w for w in capture.warnings)


def test_all_poses_bad_is_an_error(tmp_path):
    names = ["a.png", "b.png"]
    write_photo_folder(tmp_path / "images", 2, (W, H), names=names)
    cameras, images = _model(ring_poses(2), names)
    images = [(i, np.array([np.nan] * 4), t, c, n) for i, q, t, c, n in images]
    write_colmap_text(tmp_path / "sparse" / "0", cameras, images)
    with pytest.raises(CaptureError, match="no posed photos") as error:
        load_capture(tmp_path)
    assert "sparse" in str(error.value)


def test_camera_size_mismatch_names_the_image(tmp_path):
    names = ["a.png", "b.png"]
    write_photo_folder(tmp_path / "images", 2, (50, 50), names=names)
    cameras, images = _model(ring_poses(2), names)
    write_colmap_text(tmp_path / "sparse" / "0", cameras, images)
    with pytest.raises(CaptureError, match=r"no posed photos after skipping 2 unusable photo\(s\): a\.png \(50 x 50, "
                                           r"while .*cameras\.txt \(camera 1\) states a 64 x 48 camera"):
        load_capture(tmp_path)


def test_one_photo_of_another_aspect_ratio_is_skipped_with_a_warning(tmp_path):
    names = ["a.png", "b.png", "c.png"]
    write_photo_folder(tmp_path / "images", 3, (W, H), names=names)
    write_photo_folder(tmp_path / "images", 1, (50, 50), names=["b.png"], seed=7)
    cameras, images = _model(ring_poses(3), names)
    write_colmap_text(tmp_path / "sparse" / "0", cameras, images)
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == ["a.png", "c.png"]
    assert any(w.startswith("1 photo(s) skipped") and "b.png (50 x 50, while" in w for w in capture.warnings)


def test_truncated_binary_model_is_reported(tmp_path):
    names = ["a.png", "b.png"]
    write_photo_folder(tmp_path / "images", 2, (W, H), names=names)
    cameras, images = _model(ring_poses(2), names)
    folder = write_colmap_binary(tmp_path / "sparse" / "0", cameras, images)
    data = (folder / "images.bin").read_bytes()
    (folder / "images.bin").write_bytes(data[:40])
    with pytest.raises(CaptureError, match="images.bin is truncated"):
        load_capture(tmp_path)


def test_photos_kept_elsewhere_are_found_with_the_images_dir_the_error_names(tmp_path):
    import argparse

    from engine.poses.cli import add_arguments as poses_arguments
    from engine.recon.cli import add_arguments as reconstruct_arguments

    poses = ring_poses(3)
    names = ["a.png", "b.png", "c.png"]
    write_photo_folder(tmp_path / "photos", 3, (W, H), names=names)
    cameras, images = _model(poses, names)
    write_colmap_text(tmp_path / "model", cameras, images)
    with pytest.raises(CaptureError, match="--images-dir FOLDER"):
        load_capture(tmp_path / "model")
    # The flag the error names exists on the commands that load a capture, and it finds the photos.
    for add_arguments in (reconstruct_arguments, poses_arguments):
        parser = argparse.ArgumentParser()
        add_arguments(parser)
        args = parser.parse_args([str(tmp_path / "model"), "--images-dir", str(tmp_path / "photos"), "--out", "room.ply"])
        capture = load_capture(args.capture, images_dir=args.images_dir)
        assert [f.image_path.parent for f in capture.frames] == [tmp_path / "photos"] * 3
