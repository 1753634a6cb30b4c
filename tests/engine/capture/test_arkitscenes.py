"""ARKitScenes' raw layout: detected with no flag, photos turned upright with their depth, metric poses.

The export is written by hand (tests/fixtures_arkitscenes.py) the way ARKitScenes stores an iPad held
upright. A marker painted where a known world point
projects in a stored photo must be found where the loaded camera projects that point in the loaded
photo; the depth stored there must come back at the same pixel.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.capture import load_capture
from engine.capture.detect import detect_format
from engine.capture.sensor_depth import read_sensor_depth
from engine.errors import CaptureError
from engine.geometry.cameras import project_points, turned_clockwise, upright_quarter_turns
from fixtures_arkitscenes import H, K, POINT, W, capture_poses, write_arkitscenes

def test_the_stored_photos_are_turned_as_an_upright_ipad_stores_them():
    # the fixture itself: world up points to the stored photo's left (-x), so one clockwise turn rights it
    poses = np.stack(capture_poses())
    assert np.all(poses[:, :3, 0] @ np.array([0.0, 0.0, 1.0]) < -0.9)
    assert upright_quarter_turns(poses) == 1


def test_detected_with_no_flag_turned_upright_metric(tmp_path):
    poses = capture_poses()
    folder = write_arkitscenes(tmp_path / "123", poses, [10.0, 10.1, 10.2, 10.3])
    assert detect_format(folder) == "arkitscenes"
    assert detect_format(folder / "123_frames") == "arkitscenes"
    capture = load_capture(folder, cache_dir=tmp_path / "cache")
    assert capture.format == "arkitscenes" and capture.metric and len(capture.frames) == 4
    assert capture.pose_origin == "ARKit (ARKitScenes)"
    assert any("turned upright (90 deg clockwise)" in note for note in capture.notes)
    for frame, given in zip(capture.frames, poses):
        assert (frame.width, frame.height) == (H, W)  # portrait now
        assert frame.pose[:3, 1] @ np.array([0.0, 0.0, 1.0]) < -0.9  # image down is world down
        np.testing.assert_allclose(frame.pose[:3, 3], given[:3, 3], atol=1e-6)  # metres, the same world
        photo = cv2.imread(str(frame.image_path))
        assert photo.shape == (W, H, 3)
        assert photo[:4, :, 2].mean() > 150 and photo[-4:, :, 2].mean() < 100  # the red edge is on top
        u, v, z = (float(a[0]) for a in project_points(POINT[None], frame.K, frame.pose))
        assert photo[int(v), int(u)].min() == 255, "the marker is where the loaded camera sees the point"
        depth, confidence = read_sensor_depth(frame.sensor_depth)
        assert confidence is None and depth.shape == (W, H)
        assert depth[int(v), int(u)] == pytest.approx(z, abs=0.001)


def test_turning_a_camera_keeps_what_each_pixel_sees():
    # turned_clockwise against the image turned by numpy: the same world point at the turned pixel
    pose = capture_poses()[0]
    u, v, _ = (float(a[0]) for a in project_points(POINT[None], K, pose))
    for turns in range(4):
        turned_K, turned_pose, size = turned_clockwise(K, pose, (W, H), turns)
        image = np.zeros((H, W), np.uint8)
        image[int(v), int(u)] = 1
        turned = np.rot90(image, -turns)
        assert (turned.shape[1], turned.shape[0]) == size
        tu, tv, _ = (float(a[0]) for a in project_points(POINT[None], turned_K, turned_pose))
        assert turned[int(tv), int(tu)] == 1


def test_photos_without_a_pose_within_5_ms_are_skipped_and_named(tmp_path):
    poses = capture_poses()
    folder = write_arkitscenes(tmp_path / "123", poses, [10.0, 10.1, 10.2, 10.3],
                               traj_times=[10.0, 10.1, 10.2, 10.32])
    capture = load_capture(folder, cache_dir=tmp_path / "cache")
    assert len(capture.frames) == 3
    assert any("123_10.300.png" in w and "5 ms" in w for w in capture.warnings)


def test_a_damaged_trajectory_is_refused_naming_the_line(tmp_path):
    folder = write_arkitscenes(tmp_path / "123", capture_poses(), [10.0, 10.1, 10.2, 10.3])
    traj = folder / "123_frames" / "lowres_wide.traj"
    lines = traj.read_text().splitlines()
    lines[2] = "10.2 0.1 0.2"
    traj.write_text("\n".join(lines) + "\n")
    with pytest.raises(CaptureError, match=r"lowres_wide.traj, line 3: expected 7 numbers"):
        load_capture(folder, cache_dir=tmp_path / "cache")


def test_turned_photos_are_reused_until_a_source_changes(tmp_path):
    folder = write_arkitscenes(tmp_path / "123", capture_poses(), [10.0, 10.1, 10.2, 10.3])
    first = load_capture(folder, cache_dir=tmp_path / "cache")
    written = first.frames[0].image_path.stat().st_mtime_ns
    again = load_capture(folder, cache_dir=tmp_path / "cache")
    assert again.frames[0].image_path.stat().st_mtime_ns == written
