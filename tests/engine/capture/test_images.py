"""Plain photo folders: ordering, EXIF orientation and focal length, load_image."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
from PIL import Image

from engine.capture import Capture, detect_format, load_capture, load_image
from engine.capture.naming import natural_key
from fixtures_capture import textured_image, write_exif_jpeg, write_image, write_photo_folder


def _displayed(stored: np.ndarray, orientation: int) -> np.ndarray:
    """What a viewer shows for EXIF `orientation` (EXIF 2.3 table), written out independently."""
    return {
        1: lambda a: a,
        2: lambda a: a[:, ::-1],  # mirror horizontal
        3: lambda a: a[::-1, ::-1],  # rotate 180
        4: lambda a: a[::-1],  # mirror vertical
        5: lambda a: a.transpose(1, 0, 2),  # mirror horizontal + rotate 270 CW = transpose
        6: lambda a: np.rot90(a, k=-1),  # rotate 90 CW
        7: lambda a: a[::-1, ::-1].transpose(1, 0, 2),  # transverse
        8: lambda a: np.rot90(a, k=1),  # rotate 90 CCW
    }[orientation](stored)


def test_natural_order_and_any_suffix_case(tmp_path):
    names = ["frame10.JPG", "frame2.png", "Frame1.jpeg", "frame11.PNG", "notes.txt", "._frame3.jpg"]
    for i, name in enumerate(names[:4]):
        write_image(tmp_path / name, textured_image(32, 24, i))
    (tmp_path / "notes.txt").write_text("not a photo")
    (tmp_path / "._frame3.jpg").write_bytes(b"AppleDouble metadata, not a photo")

    capture = load_capture(tmp_path)

    assert isinstance(capture, Capture) and capture.format == "images"
    assert [f.name for f in capture.frames] == ["Frame1.jpeg", "frame2.png", "frame10.JPG", "frame11.PNG"]
    assert capture.resolution == (32, 24)
    assert all(f.pose is None and f.K is None for f in capture.frames)  # no EXIF: K unknown
    assert capture.metric is False and capture.warnings == []
    assert natural_key("a2") < natural_key("a10") < natural_key("b1")


def test_images_subfolder_is_used(tmp_path):
    write_photo_folder(tmp_path / "images", 3)
    (tmp_path / "readme.txt").write_text("x")
    capture = load_capture(tmp_path)
    assert capture.format == "images" and capture.root == tmp_path
    assert [f.image_path.parent for f in capture.frames] == [tmp_path / "images"] * 3


@pytest.mark.parametrize("suffix", [".png", ".jpg"])
def test_load_image_applies_every_exif_orientation(tmp_path, suffix):
    stored = textured_image(40, 24, seed=3)  # W 40 x H 24: asymmetric so every transform differs
    stored[:4, :8] = (255, 0, 0)  # a red corner marks the top-left
    for orientation in range(1, 9):
        exif = Image.Exif()
        exif[0x0112] = orientation
        path = tmp_path / f"o{orientation}{suffix}"
        Image.fromarray(stored).save(path, exif=exif, quality=98)
        loaded = load_image(path)
        expected = _displayed(np.asarray(Image.open(path).convert("RGB")), orientation)
        assert loaded.dtype == np.uint8 and loaded.shape == expected.shape, orientation
        tolerance = 0 if suffix == ".png" else 8  # two JPEG decoders may differ by a few levels
        assert np.abs(loaded.astype(int) - expected.astype(int)).max() <= tolerance, orientation
        if suffix == ".png":
            assert np.array_equal(loaded, _displayed(stored, orientation)), orientation


def test_frame_size_follows_orientation_and_matches_pixels(tmp_path):
    stored = textured_image(60, 40, seed=1)  # stored landscape
    write_exif_jpeg(tmp_path / "a.jpg", stored, orientation=6)  # displayed portrait
    write_exif_jpeg(tmp_path / "b.jpg", textured_image(60, 40, seed=2), orientation=8)
    capture = load_capture(tmp_path)
    assert capture.resolution == (40, 60)
    for frame in capture.frames:
        assert load_image(frame.image_path).shape == (frame.height, frame.width, 3)


def test_exif_35mm_focal_gives_K_in_displayed_pixels(tmp_path):
    for i in range(2):
        write_exif_jpeg(tmp_path / f"p{i}.jpg", textured_image(80, 60, i), orientation=6, focal_35mm=28)
    capture = load_capture(tmp_path)
    frame = capture.frames[0]
    # 35 mm equivalence keeps the diagonal field of view: f = 28 mm * diagonal_px / 43.27 mm.
    expected_f = 28.0 * math.hypot(80, 60) / math.hypot(36, 24)
    assert (frame.width, frame.height) == (60, 80)
    np.testing.assert_allclose(frame.K, [[expected_f, 0, 30.0], [0, expected_f, 40.0], [0, 0, 1]], rtol=1e-9)


def test_exif_focal_plane_resolution_gives_K(tmp_path):
    # 4.5 mm lens, 200 pixels per mm on the sensor (unit 4 = mm) -> 900 px.
    for i in range(2):
        write_exif_jpeg(tmp_path / f"p{i}.jpg", textured_image(64, 48, i), focal_mm=4.5,
                        focal_plane_x_resolution=200.0, focal_plane_unit=4)
    frame = load_capture(tmp_path).frames[1]
    np.testing.assert_allclose(frame.K[0, 0], 900.0, rtol=1e-9)
    np.testing.assert_allclose(frame.K[:2, 2], [32.0, 24.0])


def test_partial_exif_warns_and_leaves_K_unknown(tmp_path):
    write_exif_jpeg(tmp_path / "a.jpg", textured_image(64, 48, 0), focal_35mm=30)
    write_exif_jpeg(tmp_path / "b.jpg", textured_image(64, 48, 1))
    capture = load_capture(tmp_path)
    assert capture.frames[0].K is not None and capture.frames[1].K is None
    assert any("only 1 of 2" in w for w in capture.warnings)


def test_metric_option_is_ignored_without_poses(tmp_path):
    write_photo_folder(tmp_path, 2)
    capture = load_capture(tmp_path, metric=True)
    assert capture.metric is False and any("metric=True ignored" in w for w in capture.warnings)


def test_detect_format_of_each_layout(tmp_path):
    write_photo_folder(tmp_path / "photos", 2)
    assert detect_format(tmp_path / "photos") == "images"
    shutil.copytree(tmp_path / "photos", tmp_path / "proj" / "images")
    (tmp_path / "proj" / "transforms.json").write_text('{"frames": []}')
    assert detect_format(tmp_path / "proj") == "transforms"
    (tmp_path / "scan" / "color").mkdir(parents=True)
    (tmp_path / "scan" / "pose").mkdir()
    assert detect_format(tmp_path / "scan") == "scannet"
    (tmp_path / "walk.MOV").write_bytes(b"")
    assert detect_format(tmp_path / "walk.MOV") == "video"
