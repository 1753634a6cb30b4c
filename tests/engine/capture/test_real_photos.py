"""Real photo sets from ../shared/data (skipped with a message when absent). Never writes there:
derived images go to tmp_path through cache_dir."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import shared_dataset
from engine.capture import load_capture, load_image

SCEAUX_FOCAL = 2905.88  # K.txt of the data set, at 2832 x 2128


def test_fox_transforms_json(tmp_path):
    fox = shared_dataset("fox")
    capture = load_capture(fox, undistort=False)
    assert capture.format == "transforms" and capture.metric is False
    assert len(capture.frames) == 50 and len(capture.posed_frames) == 50
    assert capture.resolution == (1080, 1920)
    listed = [f["file_path"] for f in json.loads((fox / "transforms.json").read_text())["frames"]]
    missing = [p for p in listed if not (fox / p).is_file()]
    assert len(missing) == 17
    warning = next(w for w in capture.warnings if "missing images" in w)
    assert "17 frame(s)" in warning and all(p in warning for p in missing)
    np.testing.assert_allclose(capture.frames[0].K, [[1375.52, 0, 554.558], [0, 1374.49, 965.268], [0, 0, 1]])
    assert any("undistort=False" in w for w in capture.warnings)  # the file has k1 k2 p1 p2

    # OpenGL -> OpenCV: the optical axes (+z) must meet in front of every camera, 3.7-4.8 units away.
    centres = np.array([f.pose[:3, 3] for f in capture.frames])
    axes = np.array([f.pose[:3, 2] for f in capture.frames])
    projectors = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    focus = np.linalg.solve(projectors.sum(0), np.einsum("nij,nj->i", projectors, centres))
    depths = np.einsum("ni,ni->n", focus[None] - centres, axes)
    assert np.all(depths > 2.0) and np.all(depths < 8.0), depths  # in front (+z): flipped axes would be < 0


def test_fox_undistorted_into_cache(tmp_path):
    fox = shared_dataset("fox")
    before = sorted(p.name for p in fox.iterdir())
    capture = load_capture(fox, cache_dir=tmp_path, verify_images=False)
    frame = capture.frames[0]
    assert frame.image_path.is_relative_to(tmp_path)
    assert load_image(frame.image_path).shape == (1920, 1080, 3)
    assert abs(frame.K[0, 0] - 1375.52) / 1375.52 < 0.03  # a pinhole K near the original one
    assert sorted(p.name for p in fox.iterdir()) == before  # nothing written into the data set


def test_sceaux_castle_exif_focal(tmp_path):
    castle = shared_dataset("sceaux_castle")
    capture = load_capture(castle)
    assert capture.format == "images" and len(capture.frames) == 11
    assert capture.resolution == (2832, 2128)
    frame = capture.frames[0]
    assert frame.name == "100_7100.JPG"
    # EXIF FocalLengthIn35mmFilm = 35 (KODAK Z612) -> 2866 px, 1.4 % under the calibrated value.
    assert abs(frame.K[0, 0] - SCEAUX_FOCAL) / SCEAUX_FOCAL < 0.03
    np.testing.assert_allclose(frame.K[:2, 2], [1416.0, 1064.0])
    if not (castle / "images" / "K.txt").is_file():
        pytest.skip("K.txt missing")
    K_file = np.loadtxt(castle / "images" / "K.txt")
    assert abs(frame.K[0, 0] - K_file[0, 0]) / K_file[0, 0] < 0.03
