"""Bad input: every failure is a CaptureError naming the file or folder and saying what to do."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from engine.capture import load_capture, load_image
from engine.errors import CaptureError, VortxError
from fixtures_capture import textured_image, write_image, write_photo_folder


def _error(path, **options) -> str:
    with pytest.raises(CaptureError) as error:
        load_capture(path, **options)
    assert isinstance(error.value, VortxError)
    return str(error.value)


def test_path_does_not_exist(tmp_path):
    message = _error(tmp_path / "nope")
    assert str(tmp_path / "nope") in message and "does not exist" in message and "Choose" in message


def test_empty_folder(tmp_path):
    message = _error(tmp_path)
    assert str(tmp_path) in message and "is empty" in message


def test_folder_without_photos(tmp_path):
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "scan.heic").write_bytes(b"x")
    message = _error(tmp_path)
    assert f"no photos found in {tmp_path}" in message and "notes.txt" in message and ".jpg" in message


def test_single_photo_file_is_not_a_capture(tmp_path):
    path = write_image(tmp_path / "one.jpg", textured_image(32, 24))
    assert "single photo" in _error(path)


@pytest.mark.parametrize("content", [b"this is not a JPEG at all", "truncated"])
def test_corrupt_photo_is_named(tmp_path, content):
    write_photo_folder(tmp_path, 3, (320, 240), suffix=".jpg")
    if content == "truncated":  # a valid header with half the data: OpenCV would decode it silently
        data = (tmp_path / "frame1.jpg").read_bytes()
        (tmp_path / "frame1.jpg").write_bytes(data[: len(data) // 2])
    else:
        (tmp_path / "frame1.jpg").write_bytes(content)
    message = _error(tmp_path)
    assert str(tmp_path / "frame1.jpg") in message and "corrupt" in message and "remove it" in message


def test_mixed_resolutions_name_one_file_of_each_size(tmp_path):
    write_photo_folder(tmp_path, 2, (64, 48), names=["a1.png", "a2.png"])
    write_photo_folder(tmp_path, 1, (48, 64), names=["b.png"], seed=10)
    write_photo_folder(tmp_path, 1, (32, 24), names=["c.png"], seed=20)
    message = _error(tmp_path)
    assert "a1.png is 64 x 48" in message and "b.png is 48 x 64" in message and "c.png is 32 x 24" in message
    assert "different resolutions" in message and str(tmp_path) in message


def test_only_one_photo(tmp_path):
    write_photo_folder(tmp_path, 1, names=["lonely.png"])
    message = _error(tmp_path)
    assert "only 1 photo (lonely.png)" in message and "at least 2" in message


def test_duplicates_are_dropped_with_a_warning(tmp_path):
    write_photo_folder(tmp_path, 3)
    shutil.copy(tmp_path / "frame1.png", tmp_path / "frame7.png")  # the later one in frame order goes
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == ["frame0.png", "frame1.png", "frame2.png"]
    assert any("frame7.png (same as frame1.png)" in w for w in capture.warnings)


def test_duplicates_leaving_one_photo_say_so(tmp_path):
    write_photo_folder(tmp_path, 1, names=["a.png"])
    shutil.copy(tmp_path / "a.png", tmp_path / "b.png")
    message = _error(tmp_path)
    assert "only 1 photo (a.png) after dropping 1 byte-identical duplicate" in message


def test_folder_with_only_a_video_points_at_it(tmp_path):
    (tmp_path / "room.mp4").write_bytes(b"x")
    assert "room.mp4" in _error(tmp_path) and "choose the video file itself" in _error(tmp_path)


def test_bad_options(tmp_path):
    write_photo_folder(tmp_path, 2)
    assert "fps" in _error(tmp_path, fps=0)
    assert "blur_fraction" in _error(tmp_path, blur_fraction=1.5)
    assert "unknown capture format" in _error(tmp_path, format="nerf")
    with pytest.raises(TypeError, match="fsp"):
        load_capture(tmp_path, fsp=3)


def test_load_image_errors_name_the_file(tmp_path):
    with pytest.raises(CaptureError, match="missing.png"):
        load_image(tmp_path / "missing.png")
    (tmp_path / "junk.jpg").write_bytes(b"junk")
    with pytest.raises(CaptureError, match="junk.jpg"):
        load_image(tmp_path / "junk.jpg")


def test_grey_and_alpha_pngs_load_as_rgb(tmp_path):
    import cv2

    cv2.imwrite(str(tmp_path / "grey.png"), np.full((24, 32), 77, np.uint8))
    cv2.imwrite(str(tmp_path / "alpha.png"), np.full((24, 32, 4), 200, np.uint8))
    for name in ("grey.png", "alpha.png"):
        image = load_image(tmp_path / name)
        assert image.shape == (24, 32, 3) and image.dtype == np.uint8
    assert len(load_capture(tmp_path).frames) == 2
