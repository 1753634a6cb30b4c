"""The 3D Scanner App's "All Data" export: ARKit poses, intrinsics and LiDAR depth, read as they come."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from engine.capture import load_capture
from engine.capture.cli_info import describe, format_text
from engine.capture.sensor_depth import read_sensor_depth
from engine.errors import CaptureError
from engine.geometry.cameras import project_points
from fixtures_phone import CORRIDOR, DH, DW, K, project_arkit, walk, write_export

def test_poses_are_arkit_turned_z_up_and_project_as_the_app_says(tmp_path):
    transforms = walk(6)
    capture = load_capture(write_export(tmp_path / "scan", transforms))

    assert capture.format == "3dscannerapp" and capture.metric is True
    assert capture.pose_origin == "ARKit (3D Scanner App)"
    assert [f.name for f in capture.frames] == [f"frame_{i:05d}.jpg" for i in range(6)]
    point_arkit = np.array([0.8, 1.1, -3.0])  # in front of every camera of the walk
    point_engine = np.array([point_arkit[0], -point_arkit[2], point_arkit[1]])  # Z up: ARKit's y is up
    for frame, transform in zip(capture.frames, transforms):
        np.testing.assert_allclose(frame.K, K)
        u, v, z = project_points(point_engine[None], frame.K, frame.pose)
        np.testing.assert_allclose([u[0], v[0]], project_arkit(transform, point_arkit), atol=1e-9)
        assert z[0] > 0
        # The phone was held upright: the camera's up (OpenCV -y) is the world's +Z.
        np.testing.assert_allclose(-frame.pose[:3, 1], [0.0, 0.0, 1.0], atol=1e-12)


def test_sensor_depth_and_confidence_read_back_in_metres(tmp_path):
    capture = load_capture(write_export(tmp_path / "scan", walk(4)))
    for i, frame in enumerate(capture.frames):
        depth, confidence = read_sensor_depth(frame.sensor_depth)
        assert depth.shape == (DH, DW) and depth.dtype == np.float32
        np.testing.assert_allclose(depth, 1.0 + 0.1 * i, rtol=1e-6)
        assert (confidence[:, : DW // 2] == 2).all() and (confidence[:, DW // 2:] == 0).all()


def test_tracked_frames_without_photos_are_not_frames(tmp_path):
    """The app tracks every frame but keeps a photo of every third: 12 JSONs, 4 photos."""
    capture = load_capture(write_export(tmp_path / "scan", walk(12), every_photo=3))
    assert [f.name for f in capture.frames] == ["frame_00000.jpg", "frame_00003.jpg", "frame_00006.jpg", "frame_00009.jpg"]
    assert capture.warnings == []
    text = format_text(describe(capture))
    assert "frames      4" in text and "ARKit (3D Scanner App)" in text and "depth maps for 4 of 4" in text


def test_gps_fields_never_reach_what_the_engine_reports(tmp_path):
    capture = load_capture(write_export(tmp_path / "scan", walk(3)))
    summary = json.dumps(describe(capture))
    assert "37.544" not in summary and "126.96" not in summary and "latitude" not in summary


def test_a_photo_without_its_json_is_skipped_and_named(tmp_path):
    folder = write_export(tmp_path / "scan", walk(5))
    (folder / "frame_00002.json").unlink()
    (folder / "frame_00004.json").write_text("{ not json")
    capture = load_capture(folder)
    assert [f.name for f in capture.frames] == ["frame_00000.jpg", "frame_00001.jpg", "frame_00003.jpg"]
    text = " ".join(capture.warnings)
    assert "frame_00002.jpg" in text and "no frame_NNNNN.json" in text
    assert "frame_00004.json (not valid JSON" in text


def test_a_corrupt_depth_map_keeps_its_photo_without_depth(tmp_path):
    folder = write_export(tmp_path / "scan", walk(4))
    (folder / "depth_00001.png").write_bytes(b"\x89PNG truncated")
    capture = load_capture(folder)
    assert len(capture.frames) == 4
    assert capture.frames[1].sensor_depth is None and capture.frames[2].sensor_depth is not None
    assert any("depth_00001.png" in w and "without depth" in w for w in capture.warnings)


def test_an_export_without_any_json_is_refused_with_what_to_do(tmp_path):
    folder = write_export(tmp_path / "scan", walk(3))
    for record in folder.glob("frame_*.json"):
        record.write_text(json.dumps({"intrinsics": K.reshape(-1).tolist()}))
    with pytest.raises(CaptureError, match=r"no photo of .* has a usable pose .*cameraPoseARFrame.*\"All Data\""):
        load_capture(folder)


def test_the_zipped_export_loads_as_the_folder(tmp_path):
    folder = write_export(tmp_path / "scan", walk(4))
    archive = tmp_path / "scan.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for path in sorted(folder.iterdir()):
            zf.write(path, f"My Room/{path.name}")  # the app's share sheet zips the folder itself
    capture = load_capture(archive, cache_dir=tmp_path / "cache")
    assert capture.format == "3dscannerapp" and len(capture.frames) == 4
    np.testing.assert_allclose(capture.frames[2].pose, load_capture(folder).frames[2].pose)
    assert any("scan.zip unpacked into" in note for note in capture.notes)


def test_a_zip_that_would_write_outside_its_folder_is_refused(tmp_path):
    archive = tmp_path / "evil.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr("../outside.txt", "x")
    with pytest.raises(CaptureError, match="outside the folder"):
        load_capture(archive, cache_dir=tmp_path / "cache")
    assert not (tmp_path / "cache" / "outside.txt").exists() and not (tmp_path / "outside.txt").exists()


@pytest.mark.skipif(not CORRIDOR.is_dir(), reason=f"the 3D Scanner App corridor sample is not at {CORRIDOR} (fetch "
                    "github PyojinKim/3dScannerApp_samples, folder rgbd_dataset_renaissance_03_corridor01/All_Data, "
                    "or set VORTX_CORRIDOR)")
def test_the_real_corridor_export_loads_as_it_comes():
    capture = load_capture(CORRIDOR)
    assert capture.format == "3dscannerapp" and len(capture.frames) == 146 and capture.metric
    assert capture.frames_with_sensor_depth == 146 and capture.resolution == (1920, 1440)
    ups = np.stack([-f.pose[:3, 1] for f in capture.frames])
    assert ups[:, 2].min() > 0.9  # held upright: gravity from ARKit puts every camera's up near +Z
    # LiDAR of neighbouring frames agrees in the world: the poses and the depth share one convention.
    a, b = capture.frames[10], capture.frames[11]
    depth_a, conf_a = read_sensor_depth(a.sensor_depth)
    depth_b, _ = read_sensor_depth(b.sensor_depth)
    h, w = depth_a.shape
    scale = np.diag([w / a.width, h / a.height, 1.0])
    v, u = np.nonzero((depth_a > 0) & (conf_a == 2))
    rays = np.linalg.inv(scale @ a.K) @ np.stack([u + 0.5, v + 0.5, np.ones_like(u, dtype=float)])
    world = (a.pose[:3, :3] @ (rays * depth_a[v, u]) + a.pose[:3, 3:4]).T
    ub, vb, zb = project_points(world, scale @ b.K, b.pose)
    inside = (zb > 0) & (ub >= 0) & (ub < w) & (vb >= 0) & (vb < h)
    seen = depth_b[vb[inside].astype(int), ub[inside].astype(int)]
    error = np.abs(seen - zb[inside])[seen > 0]
    assert inside.mean() > 0.4 and np.mean(error < 0.05) > 0.9
