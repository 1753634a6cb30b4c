"""COLMAP sparse points (points3D.txt / .bin): read with their colours, carried by the loaded capture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.capture import load_capture
from engine.capture.colmap_model import read_model, read_points
from engine.errors import CaptureError
from fixtures_capture import colmap_image_entry, ring_poses, write_colmap_binary, write_colmap_text, write_photo_folder

W, H = 64, 48
XYZ = np.array([[0.1, 0.2, 0.3], [-1.0, 2.5, 0.0], [3.0, -0.5, 1.25]])
RGB = np.array([[255, 0, 10], [0, 128, 255], [7, 8, 9]], dtype=np.uint8)


def _pycolmap_model(folder: Path, kind: str) -> None:
    pycolmap = pytest.importorskip("pycolmap")
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=W, height=H,
                                                    params=[60.0, 60.0, 32.0, 24.0], camera_id=1))
    for i, pose in enumerate(ring_poses(2)):
        world_to_camera = np.linalg.inv(pose)
        rigid = pycolmap.Rigid3d(pycolmap.Rotation3d(world_to_camera[:3, :3]), world_to_camera[:3, 3])
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"v{i}.png", camera_id=1, image_id=i + 1), rigid)
    for xyz, rgb in zip(XYZ, RGB):
        rec.add_point3D(xyz, pycolmap.Track(), rgb)
    folder.mkdir(parents=True)
    (rec.write_text if kind == "text" else rec.write_binary)(str(folder))


@pytest.mark.parametrize("kind", ["text", "binary"])
def test_points_of_a_pycolmap_written_model(tmp_path: Path, kind: str) -> None:
    _pycolmap_model(tmp_path / "m", kind)
    points = read_points(tmp_path / "m", read_model(tmp_path / "m").kind)
    assert points is not None
    order = np.argsort(points.xyz[:, 0])  # COLMAP may write the points in any order
    np.testing.assert_allclose(points.xyz[order], XYZ[np.argsort(XYZ[:, 0])], atol=1e-12)
    np.testing.assert_array_equal(points.rgb[order], RGB[np.argsort(XYZ[:, 0])])


def _capture_folder(tmp_path: Path, writer) -> Path:
    names = [f"{i}.png" for i in range(3)]
    write_photo_folder(tmp_path / "images", 3, (W, H), names=names)
    images = [colmap_image_entry(i + 1, pose, 1, name) for i, (pose, name) in enumerate(zip(ring_poses(3), names))]
    writer(tmp_path / "sparse" / "0", [(1, "PINHOLE", W, H, (60.0, 60.0, 32.0, 24.0))], images)
    return tmp_path / "sparse" / "0"


def test_loaded_capture_carries_the_text_model_points(tmp_path: Path) -> None:
    model = _capture_folder(tmp_path, write_colmap_text)
    lines = ["# 3D point list"] + [f"{i + 1} {x!r} {y!r} {z!r} {r} {g} {b} 0.5 1 0 2 0"
                                     for i, ((x, y, z), (r, g, b)) in enumerate(zip(XYZ.tolist(), RGB.tolist()))]
    (model / "points3D.txt").write_text("\n".join(lines) + "\n")
    capture = load_capture(tmp_path)
    np.testing.assert_allclose(capture.points, XYZ)
    np.testing.assert_array_equal(capture.point_colors, RGB)


def test_model_without_points_has_none_and_a_broken_points_file_is_a_warning(tmp_path: Path) -> None:
    model = _capture_folder(tmp_path, write_colmap_binary)  # writes an empty points3D.bin
    assert load_capture(tmp_path).points is None
    (model / "points3D.bin").write_bytes(b"\x05\x00\x00\x00\x00\x00\x00\x00" + b"\x00" * 20)  # 5 points, 20 bytes
    with pytest.raises(CaptureError, match="points3D.bin is truncated"):
        read_points(model, "binary")
    capture = load_capture(tmp_path)
    assert capture.points is None and len(capture.frames) == 3
    assert any("sparse points left out" in w and "points3D.bin" in w for w in capture.warnings)
