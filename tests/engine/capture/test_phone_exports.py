"""Stray Scanner, Record3D and Polycam exports: detected from the folder (or zip), ARKit poses, LiDAR depth.

Each fixture is written here the way the app writes it (see each loader's docstring for the sources),
with hand-written ARKit camera-to-world transforms (camera x right / y up / z backward, world y up).
The expected pixels are computed by ARKit's convention, independently of the engine's mapping.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Optional

import cv2
import lzfse
import numpy as np
import pytest

from engine.capture import detect_format, load_capture
from engine.capture.sensor_depth import read_sensor_depth
from engine.errors import CaptureError
from engine.geometry.cameras import project_points
from fixtures_capture import draw_room_lines, look_yaw_pitch, rotation_to_quaternion, textured_image, write_image, write_video

W, H = 64, 48  # photos and video frames
DW, DH = 16, 12  # depth maps: the photo's aspect ratio, as the apps write them (256 x 192 for 1920 x 1440)
K = np.array([[52.0, 0.0, 31.0], [0.0, 53.0, 24.5], [0.0, 0.0, 1.0]])
POINT_ARKIT = np.array([0.8, 1.1, -3.0])  # in front of every camera of `walk`
POINT_ENGINE = np.array([POINT_ARKIT[0], -POINT_ARKIT[2], POINT_ARKIT[1]])  # Z up: ARKit's y is up, -z ahead


def arkit_transform(yaw_deg: float, pitch_deg: float, position: tuple[float, float, float]) -> np.ndarray:
    """ARKit camera-to-world (4, 4): turned by `yaw_deg` about the world's vertical y, then tilted up by
    `pitch_deg` about the camera's x, at `position` (ARKit world, y up, metres)."""
    a, p = np.radians(yaw_deg), np.radians(pitch_deg)
    yaw = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    pitch = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(p), -np.sin(p)], [0.0, np.sin(p), np.cos(p)]])
    transform = np.eye(4)
    transform[:3, :3] = yaw @ pitch
    transform[:3, 3] = position
    return transform


def walk(count: int) -> list[np.ndarray]:
    """A short walk: turning 10 deg a frame, tilted alternately down and up, never the zero pose."""
    return [arkit_transform(10.0 * i, -8.0 if i % 2 == 0 else 6.0, (0.3 * i, 1.4, -0.2 * i)) for i in range(count)]


def project_arkit(transform: np.ndarray, K_: np.ndarray, point_arkit: np.ndarray) -> tuple[float, float]:
    """Pixel of an ARKit world point by ARKit's own convention: a point in front has camera z < 0, and
    image rows grow downwards, against camera y."""
    x, y, z = (np.linalg.inv(transform) @ np.append(point_arkit, 1.0))[:3]
    assert z < 0, "the test point must be in front of the camera"
    return K_[0, 0] * x / -z + K_[0, 2], K_[1, 1] * -y / -z + K_[1, 2]


def assert_projects_as_arkit(capture, transforms: list[np.ndarray], K_: np.ndarray = K) -> None:
    for frame, transform in zip(capture.frames, transforms):
        u, v, z = project_points(POINT_ENGINE[None], frame.K, frame.pose)
        assert z[0] > 0
        np.testing.assert_allclose([u[0], v[0]], project_arkit(transform, K_, POINT_ARKIT), atol=1e-6)


def depth_mm(i: int) -> np.ndarray:
    """(DH, DW) uint16 millimetres of frame i: a slanted plane, distinct per frame."""
    return (1000 + 100 * i + 7 * np.arange(DW)[None, :] + 3 * np.arange(DH)[:, None]).astype(np.uint16)


def confidence(i: int) -> np.ndarray:
    """(DH, DW) uint8 ARKit confidence: high on the left half, low on the right."""
    values = np.zeros((DH, DW), np.uint8)
    values[:, : DW // 2] = 2
    return values


def quaternion_xyzw(rotation: np.ndarray) -> list[float]:
    w, x, y, z = rotation_to_quaternion(rotation)
    return [float(x), float(y), float(z), float(w)]


def zip_folder(folder: Path, archive: Path, top: Optional[str]) -> Path:
    """`folder`'s files zipped under `top`/ (a shared folder) or at the root (Record3D's .r3d)."""
    with zipfile.ZipFile(archive, "w") as zf:
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            name = path.relative_to(folder).as_posix()
            zf.write(path, f"{top}/{name}" if top else name)
    return archive


# ---------------------------------------------------------------- Stray Scanner

def write_stray(folder: Path, transforms: list[np.ndarray], seconds_apart: float = 0.5,
                video_frames: Optional[int] = None) -> Path:
    """A Stray Scanner recording: rgb.mp4, odometry.csv (the rotation turned half about the camera's x,
    as OdometryEncoder.swift writes it), camera_matrix.csv, depth/ and confidence/ PNGs."""
    count = len(transforms) if video_frames is None else video_frames
    write_video(folder / "rgb.mp4", [textured_image(W, H, seed=i) for i in range(count)], fps=60.0)
    app_turn = np.diag([1.0, -1.0, -1.0])  # q_AC = (1, 0, 0, 0): ARKit camera axes -> OpenCV's
    lines = ["timestamp, frame, x, y, z, qx, qy, qz, qw"]
    for i, transform in enumerate(transforms):
        x, y, z = transform[:3, 3]
        qx, qy, qz, qw = quaternion_xyzw(transform[:3, :3] @ app_turn)
        lines.append(f"{5000.25 + seconds_apart * i}, {i:06d}, {x}, {y}, {z}, {qx}, {qy}, {qz}, {qw}")
    (folder / "odometry.csv").write_text("\n".join(lines) + "\n")
    (folder / "camera_matrix.csv").write_text("\n".join(", ".join(repr(float(v)) for v in row) for row in K))
    (folder / "imu.csv").write_text("timestamp, a_x, a_y, a_z, alpha_x, alpha_y, alpha_z\n"
                                    "5000.0, 0, -9.8, 0, 0, 0, 0\n")
    for name in ("depth", "confidence"):
        (folder / name).mkdir()
    for i in range(count):
        cv2.imwrite(str(folder / "depth" / f"{i:06d}.png"), depth_mm(i))
        cv2.imwrite(str(folder / "confidence" / f"{i:06d}.png"), confidence(i))
    return folder


def test_stray_scanner_poses_intrinsics_and_depth(tmp_path):
    transforms = walk(6)
    folder = write_stray(tmp_path / "8d3a1b2c", transforms)
    capture = load_capture(folder, cache_dir=tmp_path / "cache")

    assert detect_format(folder) == "strayscanner"
    assert capture.format == "strayscanner" and len(capture.frames) == 6 and capture.metric is True
    assert capture.pose_origin == "ARKit (Stray Scanner)" and capture.warnings == []
    assert [f.name for f in capture.frames] == [f"frame_{i:06d}.jpg" for i in range(6)]
    assert all(f.image_path.parent == tmp_path / "cache" / "strayscanner-8d3a1b2c-2fps" for f in capture.frames)
    for frame in capture.frames:
        np.testing.assert_allclose(frame.K, K)
    assert_projects_as_arkit(capture, transforms)
    for i, frame in enumerate(capture.frames):
        depth, conf = read_sensor_depth(frame.sensor_depth)
        np.testing.assert_allclose(depth, depth_mm(i) / 1000.0, rtol=1e-6)
        np.testing.assert_array_equal(conf, confidence(i))
    assert load_capture(folder, cache_dir=tmp_path / "cache", metric=False).metric is False


def test_stray_scanner_keeps_about_two_frames_a_second_with_their_own_depth(tmp_path):
    transforms = walk(12)
    folder = write_stray(tmp_path / "rec", transforms, seconds_apart=0.1)  # 10 frames per second
    capture = load_capture(folder, cache_dir=tmp_path / "cache")
    assert [f.name for f in capture.frames] == ["frame_000000.jpg", "frame_000005.jpg", "frame_000010.jpg"]
    assert_projects_as_arkit(capture, [transforms[0], transforms[5], transforms[10]])
    for frame, i in zip(capture.frames, (0, 5, 10)):
        assert frame.sensor_depth.path.name == f"{i:06d}.png"
        np.testing.assert_allclose(read_sensor_depth(frame.sensor_depth)[0], depth_mm(i) / 1000.0, rtol=1e-6)
    assert any("3 of the 12 frames of rgb.mp4" in note for note in capture.notes)
    # The k-th video frame is frame k: frame_000005.jpg shows what was recorded fifth, not another frame.
    extracted = cv2.cvtColor(cv2.imread(str(capture.frames[1].image_path)), cv2.COLOR_BGR2RGB).astype(float)
    errors = [np.abs(extracted - textured_image(W, H, seed=i)).mean() for i in range(12)]
    assert int(np.argmin(errors)) == 5
    every = load_capture(folder, cache_dir=tmp_path / "cache", fps=10)
    assert len(every.frames) == 12


def test_stray_scanner_zipped_recording_loads(tmp_path):
    folder = write_stray(tmp_path / "rec", walk(4))
    archive = zip_folder(folder, tmp_path / "rec.zip", top="8d3a1b2c")
    capture = load_capture(archive, cache_dir=tmp_path / "cache")
    assert capture.format == "strayscanner" and len(capture.frames) == 4
    np.testing.assert_allclose(capture.frames[2].pose, load_capture(folder, cache_dir=tmp_path / "c2").frames[2].pose)


def test_stray_scanner_odometry_shorter_than_the_video_uses_the_posed_frames(tmp_path):
    transforms = walk(6)
    folder = write_stray(tmp_path / "rec", transforms, video_frames=8)  # the recording's last rows lost
    capture = load_capture(folder, cache_dir=tmp_path / "cache")
    assert len(capture.frames) == 6
    assert_projects_as_arkit(capture, transforms)
    assert any("odometry.csv has poses for 6 of the 8 frames of rgb.mp4" in w and "not used" in w
               for w in capture.warnings)


def test_stray_scanner_video_shorter_than_the_odometry_is_named(tmp_path):
    folder = write_stray(tmp_path / "rec", walk(6), video_frames=4)
    capture = load_capture(folder, cache_dir=tmp_path / "cache")
    assert len(capture.frames) == 4
    assert any("rgb.mp4 holds 4 frames but odometry.csv has poses up to frame 000005" in w for w in capture.warnings)


def test_stray_scanner_bad_odometry_rows_are_skipped_and_named(tmp_path):
    folder = write_stray(tmp_path / "rec", walk(5))
    lines = (folder / "odometry.csv").read_text().splitlines()
    lines[2] = "5000.75, 000001, 0.3, 1.4, -0.2, 0.0, 0.0, 0.0, 0.0"  # a zero quaternion: no rotation at all
    lines[4] = "5001.75, 000003, 0.9, oops"
    (folder / "odometry.csv").write_text("\n".join(lines) + "\n")
    capture = load_capture(folder, cache_dir=tmp_path / "cache")
    assert [f.name for f in capture.frames] == ["frame_000000.jpg", "frame_000002.jpg", "frame_000004.jpg"]
    text = " ".join(capture.warnings)
    assert "2 row(s) of odometry.csv are unusable" in text
    assert "line 3 (quaternion [0.0, 0.0, 0.0, 0.0] is not of unit length" in text
    assert "line 5 (4 fields, the header names 9)" in text


def test_stray_scanner_without_odometry_or_with_a_damaged_one_is_refused(tmp_path):
    folder = write_stray(tmp_path / "rec", walk(3))
    (folder / "odometry.csv").unlink()
    assert detect_format(folder) == "strayscanner"  # camera_matrix.csv beside rgb.mp4 still says what it is
    with pytest.raises(CaptureError, match=r"odometry\.csv is missing: it holds the camera pose of every frame"):
        load_capture(folder, cache_dir=tmp_path / "cache")
    (folder / "odometry.csv").write_text("\x00\x01garbage, no header\n")
    with pytest.raises(CaptureError, match=r"odometry\.csv does not start with the header `timestamp, frame, x, y, z"):
        load_capture(folder, cache_dir=tmp_path / "cache")
    (folder / "odometry.csv").write_text("timestamp, frame, x, y, z, qx, qy, qz, qw\n")
    with pytest.raises(CaptureError, match=r"odometry\.csv has no usable camera pose"):
        load_capture(folder, cache_dir=tmp_path / "cache")


def test_stray_scanner_damaged_camera_matrix_is_refused(tmp_path):
    folder = write_stray(tmp_path / "rec", walk(3))
    (folder / "camera_matrix.csv").write_text("1, 2\n3, 4\n")
    with pytest.raises(CaptureError, match=r"camera_matrix\.csv is not a camera matrix"):
        load_capture(folder, cache_dir=tmp_path / "cache")
    (folder / "camera_matrix.csv").write_text("1450.0, 0.0, 960.0\n0.0, 1450.0, 720.0\n0.0, 0.0, 1.0\n")
    with pytest.raises(CaptureError, match=r"principal point at \(960, 720\), outside the 64 x 48 frames of rgb\.mp4: "
                                           r"the video was resized"):
        load_capture(folder, cache_dir=tmp_path / "cache")


def test_stray_scanner_corrupt_depth_keeps_its_frame_without_depth(tmp_path):
    folder = write_stray(tmp_path / "rec", walk(4))
    (folder / "depth" / "000002.png").write_bytes(b"\x89PNG truncated")
    capture = load_capture(folder, cache_dir=tmp_path / "cache")
    assert len(capture.frames) == 4
    assert capture.frames[2].sensor_depth is None and capture.frames[1].sensor_depth is not None
    assert any("000002.png" in w and "without depth" in w for w in capture.warnings)


# ---------------------------------------------------------------- Record3D

def write_record3d(folder: Path, transforms: list[np.ndarray], seconds_apart: float = 0.5,
                   stated_size: tuple[int, int] = (W, H), per_frame_K: Optional[list[np.ndarray]] = None,
                   poses: Optional[list[list[float]]] = None) -> Path:
    """An unpacked .r3d export: metadata (K column-major, poses [qx, qy, qz, qw, px, py, pz]) and
    rgbd/N.jpg, N.depth (LZFSE float32 metres), N.conf (LZFSE uint8)."""
    (folder / "rgbd").mkdir(parents=True)
    scale = np.diag([stated_size[0] / W, stated_size[1] / H, 1.0])
    if poses is None:
        poses = [quaternion_xyzw(t[:3, :3]) + t[:3, 3].tolist() for t in transforms]
    metadata = {"w": stated_size[0], "h": stated_size[1], "dw": DW, "dh": DH, "fps": 60, "cameraType": 1,
                "K": (scale @ K).T.reshape(-1).tolist(), "poses": poses, "initPose": [0, 0, 0, 1, 0, 0, 0],
                "frameTimestamps": [812.5 + seconds_apart * i for i in range(len(poses))]}
    if per_frame_K is not None:
        metadata["perFrameIntrinsicCoeffs"] = [[k[0, 0], k[1, 1], k[0, 2], k[1, 2]] for k in per_frame_K]
    (folder / "metadata").write_text(json.dumps(metadata))
    for i in range(len(transforms)):
        write_image(folder / "rgbd" / f"{i}.jpg", textured_image(W, H, seed=i))
        metres = (depth_mm(i) / 1000.0).astype(np.float32)
        (folder / "rgbd" / f"{i}.depth").write_bytes(lzfse.compress(metres.tobytes()))
        (folder / "rgbd" / f"{i}.conf").write_bytes(lzfse.compress(confidence(i).tobytes()))
    (folder / "icon").write_bytes(b"\xff\xd8 thumbnail")
    return folder


def test_record3d_r3d_file_poses_intrinsics_and_depth(tmp_path):
    transforms = walk(6)
    folder = write_record3d(tmp_path / "export", transforms)
    archive = zip_folder(folder, tmp_path / "Room 2024-05-01.r3d", top=None)
    capture = load_capture(archive, cache_dir=tmp_path / "cache")

    assert capture.format == "record3d" and len(capture.frames) == 6 and capture.metric is True
    assert capture.pose_origin == "ARKit (Record3D)" and capture.warnings == []
    assert [f.name for f in capture.frames] == [f"{i}.jpg" for i in range(6)]
    for frame in capture.frames:
        np.testing.assert_allclose(frame.K, K)  # stored column-major: read transposed
    assert_projects_as_arkit(capture, transforms)
    for i, frame in enumerate(capture.frames):
        depth, conf = read_sensor_depth(frame.sensor_depth)
        np.testing.assert_allclose(depth, depth_mm(i) / 1000.0, rtol=1e-6)
        np.testing.assert_array_equal(conf, confidence(i))
    folder_capture = load_capture(folder)
    assert detect_format(folder) == "record3d" and len(folder_capture.frames) == 6
    np.testing.assert_allclose(folder_capture.frames[3].pose, capture.frames[3].pose)


def test_record3d_per_frame_intrinsics_and_a_larger_stated_size(tmp_path):
    transforms = walk(4)
    per_frame = [K + np.diag([i, i, 0.0]) for i in range(4)]  # the focal length refined during the recording
    doubled = [np.diag([2.0, 2.0, 1.0]) @ k for k in per_frame]
    capture = load_capture(write_record3d(tmp_path / "export", transforms, stated_size=(2 * W, 2 * H),
                                          per_frame_K=doubled))
    for frame, k in zip(capture.frames, per_frame):
        np.testing.assert_allclose(frame.K, k)
    assert any("metadata states a 128 x 96 camera but the images are 64 x 48" in w for w in capture.warnings)
    for frame, transform, k in zip(capture.frames, transforms, per_frame):
        u, v, _ = project_points(POINT_ENGINE[None], frame.K, frame.pose)
        np.testing.assert_allclose([u[0], v[0]], project_arkit(transform, k, POINT_ARKIT), atol=1e-6)


def test_record3d_keeps_about_two_frames_a_second(tmp_path):
    capture = load_capture(write_record3d(tmp_path / "export", walk(8), seconds_apart=1 / 6))
    assert [f.name for f in capture.frames] == ["0.jpg", "3.jpg", "6.jpg"]
    assert any("3 of the 8 posed frames kept" in note for note in capture.notes)


def test_record3d_damaged_timestamps_fall_back_to_the_frame_rate_and_say_so(tmp_path):
    """Frames 1/6 s apart by their timestamps; with the timestamps damaged, the metadata's 60 fps puts
    them 1/60 s apart, so fewer frames are kept at 2 per second, and a warning names the file."""
    folder = write_record3d(tmp_path / "export", walk(80), seconds_apart=1 / 6)
    metadata = json.loads((folder / "metadata").read_text())
    metadata["frameTimestamps"][3] = "garbled"
    (folder / "metadata").write_text(json.dumps(metadata))
    capture = load_capture(folder)
    # 80 frames at 60 fps span 1.3 s: frames 0, 30 and 60 at 2 per second (by the timestamps: 0, 3, 6, ...).
    assert [f.name for f in capture.frames] == ["0.jpg", "30.jpg", "60.jpg"]
    assert any("frameTimestamps are not all numbers" in w and "metadata" in w for w in capture.warnings)


def test_record3d_world_of_the_first_camera_is_levelled(tmp_path):
    """Record3D's world starts at the first frame's camera (the zero pose), which here looks 20 deg down:
    the loader levels it by the cameras' mean up, which these tilts (pairs of -20 and +20 deg) make exact."""
    truth = [arkit_transform(60.0 * (i // 2), -20.0 if i % 2 == 0 else 20.0, (0.2 * i, 1.5, 0.1 * i)) for i in range(6)]
    relative = [np.linalg.inv(truth[0]) @ t for t in truth]  # what the app writes: the first pose is zero
    poses = [quaternion_xyzw(t[:3, :3]) + t[:3, 3].tolist() for t in relative]
    poses[0] = [0, 0, 0, 1, 0, 0, 0]
    capture = load_capture(write_record3d(tmp_path / "export", relative, poses=poses))
    tilts = [np.degrees(np.arccos(np.clip(-f.pose[2, 1], -1, 1))) for f in capture.frames]  # camera up vs +Z
    np.testing.assert_allclose(tilts, 20.0, atol=1e-6)
    assert any("levelled by the cameras' mean up (turned 20.0 deg)" in note for note in capture.notes)
    # Levelling only turns the world: the cameras keep their relative poses (metres).
    for frame, t in zip(capture.frames[1:], relative[1:]):
        np.testing.assert_allclose(np.linalg.norm(frame.pose[:3, 3] - capture.frames[0].pose[:3, 3]),
                                   np.linalg.norm(t[:3, 3]), atol=1e-9)


def test_record3d_world_is_levelled_by_the_photos_vertical_lines(tmp_path):
    """Photos with door frames and corners, taken walking along a wall with the phone 15 deg down (the
    cameras' mean up leans with it) in a world turned as the first camera's is: the levelling takes up
    from the vertical lines, so every camera sees +Z where gravity is."""
    from engine.capture.record3d import _levelled

    K_lines = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    truth = [look_yaw_pitch([x, 1.0, 1.5], np.pi / 2 + np.radians(yaw), np.radians(-15.0))
             for x, yaw in zip(np.linspace(1.0, 5.0, 10), np.linspace(40, -40, 10))]
    frames = draw_room_lines(tmp_path, truth, K_lines, (640, 480))
    first_camera_world = np.linalg.inv(truth[0])  # Record3D's world: the first camera's axes
    in_app_world = [replace(f, pose=first_camera_world @ f.pose) for f in frames]

    levelled, note = _levelled(in_app_world)

    seen_up = [np.degrees(np.arccos(np.clip(f.pose[2, :3] @ t[2, :3], -1, 1))) for f, t in zip(levelled, truth)]
    assert max(seen_up) < 0.3
    assert "levelled by up from" in note and "vertical lines in 10 photos" in note


def test_record3d_front_camera_recording_without_poses_is_refused(tmp_path):
    folder = write_record3d(tmp_path / "export", walk(3), poses=[[0, 0, 0, 1, 0, 0, 0]] * 3)
    with pytest.raises(CaptureError, match=r"every pose in .*metadata is \[0, 0, 0, 1, 0, 0, 0\]: .*rear \(LiDAR\) "
                                           r"camera, not the front \(TrueDepth\)"):
        load_capture(folder)


def test_record3d_damaged_metadata_is_refused(tmp_path):
    folder = write_record3d(tmp_path / "export", walk(3))
    (folder / "metadata").write_text('{"w": 64, "h": 48, "poses": [[0, 0')
    with pytest.raises(CaptureError, match=r"metadata is not valid JSON .*the export is damaged; export the recording "
                                           r"from Record3D again"):
        load_capture(folder)
    (folder / "metadata").write_text(json.dumps({"w": 64, "h": 48}))
    with pytest.raises(CaptureError, match=r"metadata has no `poses` list"):
        load_capture(folder)


def test_record3d_fewer_poses_than_photos_skips_and_names_them(tmp_path):
    transforms = walk(6)
    poses = [quaternion_xyzw(t[:3, :3]) + t[:3, 3].tolist() for t in transforms[:4]]
    poses[1] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    capture = load_capture(write_record3d(tmp_path / "export", transforms, poses=poses))
    assert [f.name for f in capture.frames] == ["0.jpg", "2.jpg", "3.jpg"]
    text = " ".join(capture.warnings)
    assert "metadata has 4 poses but rgbd/ holds 6 photos" in text and "rgbd/4.jpg and rgbd/5.jpg" in text
    assert "rgbd/1.jpg (quaternion [0.0, 0.0, 0.0, 0.0] is not of unit length" in text


def test_record3d_corrupt_depth_keeps_its_photo_without_depth(tmp_path):
    folder = write_record3d(tmp_path / "export", walk(4))
    (folder / "rgbd" / "2.depth").write_bytes(b"not lzfse at all")
    (folder / "rgbd" / "3.depth").write_bytes(lzfse.compress(np.zeros(5, np.float32).tobytes()))  # wrong size
    capture = load_capture(folder)
    assert len(capture.frames) == 4 and capture.frames[1].sensor_depth is not None
    assert capture.frames[2].sensor_depth is None and capture.frames[3].sensor_depth is None
    assert any("2.depth" in w and "3.depth" in w and "without depth" in w for w in capture.warnings)


# ---------------------------------------------------------------- Polycam

def polycam_camera(transform: np.ndarray, K_: np.ndarray, size: tuple[int, int] = (W, H)) -> dict:
    record = {"fx": K_[0, 0], "fy": K_[1, 1], "cx": K_[0, 2], "cy": K_[1, 2], "width": size[0], "height": size[1],
              "blur_score": 180.5}
    record.update({f"t_{r}{c}": float(transform[r, c]) for r in range(3) for c in range(4)})
    return record


STAMPS = [98765432, 123456789, 124000000, 124500000, 125000000, 125500000]  # microseconds: 98... sorts first


def write_polycam(folder: Path, transforms: list[np.ndarray], corrected: bool = True) -> Path:
    """A raw-data export: keyframes/images + cameras (ARKit's, a little off here), corrected_images +
    corrected_cameras (the optimised ones, `transforms`), depth/ and confidence/ (0 / 127 / 255)."""
    keyframes = folder / "keyframes"
    corrected_folders = ("corrected_images", "corrected_cameras") if corrected else ()
    for name in ("images", "cameras", "depth", "confidence", *corrected_folders):
        (keyframes / name).mkdir(parents=True)
    for i, (stamp, transform) in enumerate(zip(STAMPS, transforms)):
        drifted = transform.copy()
        drifted[:3, 3] += [0.05, 0.0, 0.02]  # ARKit before Polycam's loop closure
        write_image(keyframes / "images" / f"{stamp}.jpg", textured_image(W, H, seed=i))
        raw_camera = polycam_camera(drifted if corrected else transform, K)
        (keyframes / "cameras" / f"{stamp}.json").write_text(json.dumps(raw_camera))
        if corrected:
            write_image(keyframes / "corrected_images" / f"{stamp}.jpg", textured_image(W, H, seed=100 + i))
            (keyframes / "corrected_cameras" / f"{stamp}.json").write_text(json.dumps(polycam_camera(transform, K)))
        cv2.imwrite(str(keyframes / "depth" / f"{stamp}.png"), depth_mm(i))
        cv2.imwrite(str(keyframes / "confidence" / f"{stamp}.png"), np.array([0, 127, 255], np.uint8)[confidence(i)])
    (folder / "mesh_info.json").write_text(json.dumps({"alignmentTransform": np.eye(4).reshape(-1).tolist()}))
    return folder


def test_polycam_corrected_cameras_intrinsics_and_depth(tmp_path):
    transforms = walk(6)
    folder = write_polycam(tmp_path / "capture", transforms)
    capture = load_capture(folder)

    assert detect_format(folder) == "polycam"
    assert capture.format == "polycam" and len(capture.frames) == 6 and capture.metric is True
    assert capture.pose_origin == "ARKit (Polycam)" and capture.warnings == []
    assert [f.image_path.relative_to(folder).as_posix() for f in capture.frames] == \
        [f"keyframes/corrected_images/{stamp}.jpg" for stamp in STAMPS]
    for frame in capture.frames:
        np.testing.assert_allclose(frame.K, K)
    assert_projects_as_arkit(capture, transforms)
    for i, frame in enumerate(capture.frames):
        depth, conf = read_sensor_depth(frame.sensor_depth)
        np.testing.assert_allclose(depth, depth_mm(i) / 1000.0, rtol=1e-6)
        np.testing.assert_array_equal(conf, confidence(i))  # Polycam's 0 / 127 / 255 read as ARKit's 0 / 1 / 2
    assert any("optimised poses used" in note for note in capture.notes)


def test_polycam_zipped_export_loads(tmp_path):
    folder = write_polycam(tmp_path / "capture", walk(4))
    archive = zip_folder(folder, tmp_path / "capture.zip", top="Living room")
    capture = load_capture(archive, cache_dir=tmp_path / "cache")
    assert capture.format == "polycam" and len(capture.frames) == 4
    np.testing.assert_allclose(capture.frames[1].pose, load_capture(folder).frames[1].pose)


def test_polycam_without_corrected_images_uses_the_raw_ones_and_says_so(tmp_path):
    transforms = walk(4)
    capture = load_capture(write_polycam(tmp_path / "capture", transforms, corrected=False))
    assert all(f.image_path.parent.name == "images" for f in capture.frames)
    assert_projects_as_arkit(capture, transforms)
    assert any("no corrected_images/ and corrected_cameras/" in w and "slight lens distortion" in w
               for w in capture.warnings)


def test_polycam_missing_and_corrupt_camera_files_skip_their_photos(tmp_path):
    folder = write_polycam(tmp_path / "capture", walk(5))
    cameras = folder / "keyframes" / "corrected_cameras"
    (cameras / f"{STAMPS[1]}.json").unlink()
    (cameras / f"{STAMPS[3]}.json").write_text('{"fx": 52.0, "fy"')
    capture = load_capture(folder)
    assert [f.name for f in capture.frames] == [f"{STAMPS[i]}.jpg" for i in (0, 2, 4)]
    text = " ".join(capture.warnings)
    assert f"1 photo(s) have no camera file in corrected_cameras/, skipped: {STAMPS[1]}.jpg" in text
    assert f"corrected_cameras/{STAMPS[3]}.json (not valid JSON" in text


def test_polycam_without_cameras_is_refused(tmp_path):
    folder = write_polycam(tmp_path / "capture", walk(3), corrected=False)
    for record in (folder / "keyframes" / "cameras").iterdir():
        record.unlink()
    (folder / "keyframes" / "cameras").rmdir()
    assert detect_format(folder) == "polycam"
    with pytest.raises(CaptureError, match=r"keyframes/cameras is missing: it holds the camera pose and intrinsics"):
        load_capture(folder)


def test_polycam_corrupt_depth_keeps_its_photo_without_depth(tmp_path):
    folder = write_polycam(tmp_path / "capture", walk(4))
    (folder / "keyframes" / "depth" / f"{STAMPS[2]}.png").write_bytes(b"\x89PNG truncated")
    capture = load_capture(folder)
    assert len(capture.frames) == 4 and capture.frames[2].sensor_depth is None
    assert any(f"{STAMPS[2]}.png" in w and "without depth" in w for w in capture.warnings)
