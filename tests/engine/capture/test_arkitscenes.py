"""ARKitScenes' raw layout: detected with no flag, photos turned upright with their depth, metric poses.

The export is written by hand the way ARKitScenes stores an iPad held upright: photos in the sensor's
landscape orientation (the world's up pointing to the photo's left), each line of lowres_wide.traj the
world-to-camera transform as axis-angle and translation. A marker painted where a known world point
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
from engine.geometry.cameras import look_along, project_points, turned_clockwise, upright_quarter_turns

W, H = 64, 48  # stored (landscape) photo size
K = np.array([[50.0, 0.0, 33.0], [0.0, 50.0, 22.0], [0.0, 0.0, 1.0]])
POINT = np.array([0.3, 2.0, 1.2])  # a world point (Z up, metres) every camera sees


def held_upright_on_its_side(eye, yaw_deg: float) -> np.ndarray:
    """Camera-to-world of an iPad held upright: its landscape sensor's image x points down the world
    (x = the level camera's y), image y to the left of the view (-x of the level camera)."""
    level = look_along(eye, (np.sin(np.radians(yaw_deg)), np.cos(np.radians(yaw_deg)), -0.1))
    pose = level.copy()
    pose[:3, 0], pose[:3, 1] = level[:3, 1], -level[:3, 0]
    return pose


def write_arkitscenes(folder: Path, poses: list[np.ndarray], times: list[float], traj_times=None,
                      depth: bool = True) -> Path:
    """`<folder>/123_frames/` with a photo per pose: grey, a white 3 x 3 marker where POINT projects;
    depth maps in millimetres holding the POINT's depth everywhere."""
    frames = folder / "123_frames"
    for name in ("lowres_wide", "lowres_wide_intrinsics", "lowres_depth"):
        (frames / name).mkdir(parents=True)
    lines = []
    for pose, time, traj_time in zip(poses, times, traj_times or times):
        u, v, z = (float(a[0]) for a in project_points(POINT[None], K, pose))
        photo = np.full((H, W, 3), 60, np.uint8)
        photo[int(v) - 1:int(v) + 2, int(u) - 1:int(u) + 2] = 255
        photo[:, :4, 2] = 200  # the stored photo's left edge: red in the loaded one's top rows
        cv2.imwrite(str(frames / "lowres_wide" / f"123_{time:.3f}.png"), photo)
        (frames / "lowres_wide_intrinsics" / f"123_{time:.3f}.pincam").write_text(
            f"{W} {H} {K[0, 0]} {K[1, 1]} {K[0, 2]} {K[1, 2]}\n")
        if depth:
            cv2.imwrite(str(frames / "lowres_depth" / f"123_{time:.3f}.png"), np.full((H, W), round(1000 * z), np.uint16))
        world_to_camera = np.linalg.inv(pose)
        axis_angle = cv2.Rodrigues(world_to_camera[:3, :3])[0].ravel()
        lines.append(" ".join(f"{x:.9f}" for x in [traj_time, *axis_angle, *world_to_camera[:3, 3]]))
    (frames / "lowres_wide.traj").write_text("\n".join(lines) + "\n")
    return folder


def capture_poses() -> list[np.ndarray]:
    return [held_upright_on_its_side((0.1 * i, 0.0, 1.4), yaw) for i, yaw in enumerate((-8.0, 0.0, 6.0, 12.0))]


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
