"""The SUN3D sample converter on a small stand-in with the sample's layout (the real frames are
research data fetched by hand: scripts/sun3d_room.py)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.capture import load_capture
from engine.data.sun3d import convert_sun3d, z_up_rotation
from engine.errors import VortxError
from engine.geometry.cameras import look_at


def write_sample(root: Path, frames: int = 3) -> np.ndarray:
    """A wall 1.5 m in front of cameras held 15 deg down in a y-up world (SUN3D's) with a box 1.2 m
    away in the middle of the view, in the toolbox's file layout."""
    folder = root / "fragment-1-rgbd-frames"
    folder.mkdir(parents=True)
    K = np.array([[40.0, 0, 32.0], [0, 40.0, 24.0], [0, 0, 1]])
    np.savetxt(root / "camera-intrinsics.txt", K)
    y_up = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # world z -> y: SUN3D keeps y up
    for i in range(frames):
        pose = look_at(np.array([0.1 * i, 0.0, 1.2]), np.array([0.1 * i, 1.0, 1.2 - np.tan(np.radians(15))]))
        pose[:3] = y_up @ pose[:3]
        stem = folder / f"frame-{i:06d}"
        np.savetxt(f"{stem}.pose.txt", pose)
        cv2.imwrite(f"{stem}.color.png", np.full((48, 64, 3), 90 + 20 * i, np.uint8))
        depth = np.full((48, 64), 1500, np.uint16)
        depth[16:32, 20:44] = 1200
        cv2.imwrite(f"{stem}.depth.png", depth)
    return K


def test_the_sample_becomes_a_z_up_room_with_a_fused_truth(tmp_path: Path) -> None:
    K = write_sample(tmp_path / "src")
    summary = convert_sun3d(tmp_path / "src", tmp_path / "room")
    assert summary["frames"] == 3 and summary["mesh_faces"] > 0
    capture = load_capture(tmp_path / "room")
    assert len(capture.frames) == 3 and all(f.depth_path is not None for f in capture.frames)
    np.testing.assert_allclose(capture.frames[0].K, K)
    # The sample's world up (+y) is the product's +Z, whatever the cameras' tilt (15 deg down here).
    forward = capture.frames[0].pose[:3, 2]
    assert np.degrees(np.arcsin(-forward[2])) == pytest.approx(15.0, abs=1e-6)
    assert abs(capture.frames[0].pose[:3, 0][2]) < 1e-9, "the cameras are not rolled"
    from engine.mesh_io import read_ply

    wall = read_ply(tmp_path / "room" / "mesh_gt.ply")
    centre = capture.frames[1].pose[:3, 3]
    distance = np.abs((wall.vertices - centre) @ capture.frames[1].pose[:3, 2])
    # The box's front is meshed where the sensor saw it (the wall is the volume's far end: no
    # voxels behind it, as in the SUN3D room's own outer walls).
    assert np.percentile(distance, 5) == pytest.approx(1.2, abs=0.03), "the truth is the sensor depth, fused"
    assert (tmp_path / "room" / "tsdf_gt_04.npz").is_file()


def test_missing_files_are_named(tmp_path: Path) -> None:
    write_sample(tmp_path / "src")
    (tmp_path / "src" / "fragment-1-rgbd-frames" / "frame-000001.pose.txt").unlink()
    with pytest.raises(VortxError, match="frame-000001.pose.txt is missing"):
        convert_sun3d(tmp_path / "src", tmp_path / "room")
    with pytest.raises(VortxError, match="4b4a3687"):
        convert_sun3d(tmp_path / "nothing", tmp_path / "room2")


def test_the_up_rotation_is_proper_and_takes_the_samples_up_to_z() -> None:
    R = z_up_rotation()
    np.testing.assert_allclose(R @ np.array([0, 1.0, 0]), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
