"""Writers of posed captures (ScanNet layout, COLMAP text model), read back by the loaders and pycolmap."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest

from engine.capture import load_capture
from engine.capture.writers import rotation_to_quaternion, write_colmap_text, write_scannet
from engine.capture.geometry import quaternion_to_rotation
from engine.capture.model import Capture, Frame
from engine.errors import CaptureError

K = np.array([[250.0, 0, 80.5], [0, 251.0, 60.25], [0, 0, 1]])


def random_pose(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    pose = np.eye(4)
    pose[:3, :3] = q if np.linalg.det(q) > 0 else -q
    pose[:3, 3] = rng.uniform(-4, 4, 3)
    return pose


def posed_capture(folder: Path, names: list[str], rng: np.random.Generator) -> Capture:
    folder.mkdir(parents=True, exist_ok=True)
    frames = []
    for name in names:
        image = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
        cv2.imwrite(str(folder / name), image)
        frames.append(Frame(folder / name, 160, 120, K.copy(), random_pose(rng)))
    return Capture(folder, "images", frames, metric=True)


def test_quaternion_round_trip_covers_every_pivot():
    rng = np.random.default_rng(0)
    quaternions = list(rng.standard_normal((200, 4))) + [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    for q in quaternions:
        q = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
        R = quaternion_to_rotation(q)
        back = rotation_to_quaternion(R)
        assert back[0] >= 0 and np.allclose(quaternion_to_rotation(back), R, atol=1e-12)
        assert np.allclose(back, q if q[0] >= 0 else -q, atol=1e-12)


def test_scannet_round_trip_keeps_names_order_poses_and_K(tmp_path):
    rng = np.random.default_rng(1)
    names = ["frame2.jpg", "frame10.jpg", "frame11.png", "frame1.jpg"]
    capture = posed_capture(tmp_path / "photos", names, rng)
    capture.frames[2].pose = None  # not registered: left out
    written = write_scannet(capture, tmp_path / "out")

    assert [f.name for f in written.frames] == ["frame2.jpg", "frame10.jpg", "frame1.jpg"]
    loaded = load_capture(tmp_path / "out")
    assert loaded.format == "scannet" and loaded.metric
    by_name = {f.name: f for f in loaded.frames}
    assert set(by_name) == {"frame1.jpg", "frame2.jpg", "frame10.jpg"}
    for frame in capture.posed_frames:
        assert np.array_equal(by_name[frame.name].pose, frame.pose)  # %.17g: bit-exact
        assert np.array_equal(by_name[frame.name].K, K)
        assert (tmp_path / "out" / "color" / frame.name).read_bytes() == frame.image_path.read_bytes()


def test_colmap_text_round_trip_through_pycolmap_and_the_loader(tmp_path):
    rng = np.random.default_rng(2)
    capture = posed_capture(tmp_path / "photos", [f"{i}.jpg" for i in range(5)], rng)
    capture.frames[4].K = K * [[1.2, 1, 1], [1, 1.2, 1], [1, 1, 1]]  # a second camera (zoomed)
    points = rng.uniform(-1, 1, (7, 3))
    colors = rng.integers(0, 255, (7, 3), dtype=np.uint8)
    write_colmap_text(capture, tmp_path / "model", points, colors)

    model = pycolmap.Reconstruction(str(tmp_path / "model"))
    assert model.num_cameras() == 2 and model.num_reg_images() == 5 and model.num_points3D() == 7
    for image in model.images.values():
        frame = next(f for f in capture.frames if f.name == image.name)
        cam_from_world = np.vstack([image.cam_from_world().matrix(), [0, 0, 0, 1]])
        assert np.allclose(np.linalg.inv(cam_from_world), frame.pose, atol=1e-12)
        assert np.allclose(model.cameras[image.camera_id].calibration_matrix(), frame.K)
    stored = sorted((tuple(np.round(p.xyz, 6)), tuple(p.color)) for p in model.points3D.values())
    assert stored == sorted((tuple(np.round(p, 6)), tuple(c)) for p, c in zip(points, colors))

    loaded = load_capture(tmp_path / "model", format="colmap", images_dir=tmp_path / "photos")
    assert len(loaded.frames) == 5
    for frame in loaded.frames:
        original = next(f for f in capture.frames if f.name == frame.name)
        assert np.allclose(frame.pose, original.pose, atol=1e-12)
        assert np.allclose(frame.K, original.K, atol=1e-12)


def test_scannet_refuses_to_mix_with_an_existing_capture_unless_overwriting(tmp_path):
    rng = np.random.default_rng(3)
    first = posed_capture(tmp_path / "a", ["0.jpg", "1.jpg", "2.jpg"], rng)
    second = posed_capture(tmp_path / "b", ["5.jpg"], rng)
    write_scannet(first, tmp_path / "out")
    with pytest.raises(CaptureError, match="--overwrite"):
        write_scannet(second, tmp_path / "out")
    write_scannet(second, tmp_path / "out", overwrite=True)
    assert sorted(p.name for p in (tmp_path / "out" / "color").iterdir()) == ["5.jpg"]
    assert sorted(p.name for p in (tmp_path / "out" / "pose").iterdir()) == ["5.txt"]


def test_scannet_refusals(tmp_path):
    rng = np.random.default_rng(4)
    capture = posed_capture(tmp_path / "photos", ["0.jpg", "1.jpg"], rng)
    with pytest.raises(CaptureError, match="inside the output folder"):
        write_scannet(capture, tmp_path, overwrite=True)  # would delete its own input
    capture.frames[1].K = K * 1.1
    with pytest.raises(CaptureError, match="one camera"):
        write_scannet(capture, tmp_path / "out")
    for frame in capture.frames:
        frame.pose = None
    with pytest.raises(CaptureError, match="no frame"):
        write_scannet(capture, tmp_path / "out")


def test_other_image_formats_are_reencoded_as_jpeg_and_duplicate_stems_kept_apart(tmp_path):
    rng = np.random.default_rng(5)
    image = np.zeros((120, 160, 3), np.uint8)
    image[:, :80] = 200
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    cv2.imwrite(str(tmp_path / "a" / "view.bmp"), image)
    cv2.imwrite(str(tmp_path / "b" / "view.jpg"), image)
    frames = [Frame(tmp_path / "a" / "view.bmp", 160, 120, K.copy(), random_pose(rng)),
              Frame(tmp_path / "b" / "view.jpg", 160, 120, K.copy(), random_pose(rng))]
    written = write_scannet(Capture(tmp_path, "images", frames), tmp_path / "out")
    assert [f.name for f in written.frames] == ["00000_view.jpg", "00001_view.jpg"]
    decoded = cv2.imread(str(written.frames[0].image_path))
    assert decoded.shape == (120, 160, 3) and abs(int(decoded[60, 20, 0]) - 200) < 5
