"""Bad input: every failure is a CaptureError naming the file or folder and saying what to do."""

from __future__ import annotations

import shutil
from pathlib import Path

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


def _spoil(path, how: str) -> None:
    """Make the photo at `path` unusable the way real files are."""
    if how == "truncated":  # a valid header with half the data: OpenCV would decode it silently
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif how == "empty":
        path.write_bytes(b"")
    elif how == "not an image":
        path.write_bytes(b"this is not a JPEG at all")
    else:
        raise AssertionError(how)


REASONS = {"truncated": "truncated", "empty": "an empty file (0 bytes)", "not an image": "not an image",
           "unreadable": "unreadable"}


@pytest.mark.parametrize("how", list(REASONS))
def test_bad_photo_is_skipped_with_a_warning_naming_it(tmp_path, monkeypatch, how):
    write_photo_folder(tmp_path, 4, (320, 240), suffix=".jpg")
    if how == "unreadable":  # chmod 0 would not do under root, which reads anything: refuse the read itself
        read_bytes = Path.read_bytes

        def refuse(path):
            if path.name == "frame1.jpg":
                raise PermissionError(13, "Permission denied", str(path))
            return read_bytes(path)

        monkeypatch.setattr(Path, "read_bytes", refuse)
    else:
        _spoil(tmp_path / "frame1.jpg", how)
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == ["frame0.jpg", "frame2.jpg", "frame3.jpg"]
    [warning] = [w for w in capture.warnings if "skipped" in w]
    assert warning.startswith("1 photo(s) skipped, the capture goes on without them: frame1.jpg (")
    assert REASONS[how] in warning


@pytest.mark.parametrize("how", ["truncated", "not an image"])
def test_too_few_photos_left_says_how_many_were_skipped_and_why(tmp_path, how):
    write_photo_folder(tmp_path, 3, (320, 240), suffix=".jpg")
    _spoil(tmp_path / "frame1.jpg", how)
    _spoil(tmp_path / "frame2.jpg", "empty")
    message = _error(tmp_path)
    assert f"{tmp_path} has only 1 photo (frame0.jpg) after skipping 2 unusable photo(s): frame1.jpg (" in message
    assert REASONS[how] in message and "frame2.jpg (an empty file (0 bytes))" in message
    assert "remove it from the capture" in message  # what to do about them


def test_every_photo_bad_is_an_error_naming_them(tmp_path):
    write_photo_folder(tmp_path, 2, (64, 48), suffix=".jpg")
    _spoil(tmp_path / "frame0.jpg", "truncated")
    _spoil(tmp_path / "frame1.jpg", "truncated")
    message = _error(tmp_path)
    assert "has no photos after skipping 2 unusable photo(s): frame0.jpg" in message and "frame1.jpg" in message


def test_stray_photo_of_another_size_is_skipped(tmp_path):
    write_photo_folder(tmp_path, 4, (64, 48), names=[f"a{i}.png" for i in range(4)])
    write_photo_folder(tmp_path, 1, (48, 64), names=["b.png"], seed=10)
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == [f"a{i}.png" for i in range(4)]
    assert any("b.png (48 x 64, while 4 of the 5 photos are 64 x 48)" in w for w in capture.warnings)


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
