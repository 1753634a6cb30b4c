"""instant-ngp / nerfstudio transforms.json."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine.capture import load_capture
from engine.errors import CaptureError
from fixtures_capture import project, ring_poses, write_photo_folder, write_transforms_json

W, H = 64, 48
POINT = np.array([0.2, 0.1, 0.9])


def _capture_folder(tmp_path, count=4, size=(W, H), **top_level):
    names = [f"images/{i:04d}.png" for i in range(count)]
    write_photo_folder(tmp_path, count, size, names=names)
    poses = ring_poses(count)
    write_transforms_json(tmp_path / "transforms.json", zip(names, poses), **top_level)
    return poses


def test_opengl_poses_become_opencv_and_project_correctly(tmp_path):
    poses = _capture_folder(tmp_path, fl_x=70.0, fl_y=71.0, cx=30.0, cy=26.0, w=W, h=H)
    capture = load_capture(tmp_path)
    assert capture.format == "transforms" and capture.metric is False and capture.warnings == []
    K = np.array([[70.0, 0, 30.0], [0, 71.0, 26.0], [0, 0, 1]])
    for frame, pose in zip(capture.frames, poses):
        np.testing.assert_allclose(frame.K, K)
        np.testing.assert_allclose(frame.pose, pose, atol=1e-12)
        # The camera looks at the ring's target: it must be in front (+z in OpenCV axes).
        camera_point = np.linalg.inv(frame.pose) @ np.array([0.0, 0.0, 1.0, 1.0])
        assert camera_point[2] > 0
        np.testing.assert_allclose(project(frame.K, frame.pose, POINT), project(K, pose, POINT), atol=1e-9)


def test_camera_angle_and_json_file_path(tmp_path):
    _capture_folder(tmp_path, camera_angle_x=1.0)
    capture = load_capture(tmp_path / "transforms.json")
    fx = 0.5 * W / math.tan(0.5)
    np.testing.assert_allclose(capture.frames[0].K, [[fx, 0, W / 2], [0, fx, H / 2], [0, 0, 1]])


def test_per_frame_intrinsics_override_shared_ones(tmp_path):
    import json

    _capture_folder(tmp_path, fl_x=70.0, cx=32.0, cy=24.0)
    data = json.loads((tmp_path / "transforms.json").read_text())
    data["frames"][1].update({"fl_x": 90.0, "fl_y": 91.0})
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    capture = load_capture(tmp_path)
    assert capture.frames[0].K[0, 0] == 70.0 and capture.frames[0].K[1, 1] == 70.0
    assert capture.frames[1].K[0, 0] == 90.0 and capture.frames[1].K[1, 1] == 91.0


def test_downsampled_images_get_scaled_K_with_warning(tmp_path):
    _capture_folder(tmp_path, size=(W // 2, H // 2), fl_x=70.0, fl_y=70.0, cx=32.0, cy=24.0, w=W, h=H)
    capture = load_capture(tmp_path)
    np.testing.assert_allclose(capture.frames[0].K, [[35.0, 0, 16.0], [0, 35.0, 12.0], [0, 0, 1]])
    assert any("64 x 48" in w and "32 x 24" in w for w in capture.warnings)


def test_missing_images_and_nan_poses_are_skipped_with_names(tmp_path):
    names = [f"images/{i:04d}.png" for i in range(5)]
    write_photo_folder(tmp_path, 3, (W, H), names=names[:3])
    poses = ring_poses(5)
    poses[1] = poses[1].copy()
    poses[1][0, 3] = np.nan
    write_transforms_json(tmp_path / "transforms.json", zip(names, poses), fl_x=60.0)
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == ["0000.png", "0002.png"]
    missing = next(w for w in capture.warnings if "missing" in w)
    assert "2 frame(s)" in missing and "images/0003.png" in missing and "images/0004.png" in missing
    assert any("images/0001.png" in w and "non-finite" in w for w in capture.warnings)


def test_no_usable_frame_is_an_error(tmp_path):
    write_transforms_json(tmp_path / "transforms.json", [("images/a.png", ring_poses(1)[0])], fl_x=60.0)
    with pytest.raises(CaptureError, match=r"no usable frame in .*transforms.json.*images/a.png"):
        load_capture(tmp_path)


def test_distortion_is_undistorted_into_cache(tmp_path):
    _capture_folder(tmp_path, fl_x=60.0, fl_y=60.0, cx=32.0, cy=24.0, w=W, h=H, k1=-0.2, k2=0.02, p1=0.001, p2=0.0)
    capture = load_capture(tmp_path, cache_dir=tmp_path / "cache")
    frame = capture.frames[0]
    assert frame.image_path.is_relative_to(tmp_path / "cache") and frame.image_path.is_file()
    # Barrel distortion (k1 < 0) squeezed the edges; the undistorted view without blank pixels
    # covers a little more at the edge midpoints, so its focal length is a little shorter.
    assert 50.0 < frame.K[0, 0] < 59.0
    kept = load_capture(tmp_path, undistort=False)
    assert kept.frames[0].K[0, 0] == 60.0 and any("undistort=False" in w for w in kept.warnings)


def test_metric_from_file_and_override(tmp_path):
    _capture_folder(tmp_path, fl_x=60.0, metric=True)
    assert load_capture(tmp_path).metric is True
    assert load_capture(tmp_path, metric=False).metric is False
    (tmp_path / "transforms.json").write_text((tmp_path / "transforms.json").read_text().replace('"metric": true,', ""))
    assert load_capture(tmp_path).metric is False
    assert load_capture(tmp_path, metric=True).metric is True


@pytest.mark.parametrize("extra,name", [({"camera_model": "OPENCV_FISHEYE"}, "OPENCV_FISHEYE"),
                                        ({"camera_model": "EQUIRECTANGULAR"}, "EQUIRECTANGULAR"),
                                        ({"is_fisheye": True}, "fisheye")])
def test_fisheye_cameras_are_refused(tmp_path, extra, name):
    _capture_folder(tmp_path, fl_x=60.0, **extra)
    with pytest.raises(CaptureError, match=name) as error:
        load_capture(tmp_path)
    assert "transforms.json" in str(error.value)


def test_invalid_json_names_the_file(tmp_path):
    write_photo_folder(tmp_path / "images", 2)
    (tmp_path / "transforms.json").write_text('{"frames": [ {"file_path": ')
    with pytest.raises(CaptureError, match=r"transforms.json is not valid JSON"):
        load_capture(tmp_path)
