"""The demo's photo-beside-render pictures (devtools/demo/pictures.py)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from devtools.demo.messages import DemoError
from devtools.demo.pictures import side_by_side


def test_the_photo_and_its_render_stand_side_by_side_with_a_gap(tmp_path: Path) -> None:
    photo, render, out = tmp_path / "photo.png", tmp_path / "render.png", tmp_path / "demo.png"
    cv2.imwrite(str(photo), np.full((60, 80, 3), 40, np.uint8))
    cv2.imwrite(str(render), np.full((60, 80, 3), 200, np.uint8))
    side_by_side(photo, render, out, "stereo mesh")
    picture = cv2.imread(str(out))
    assert picture.shape == (60, 164, 3)
    assert (picture[40:, 80:84] == 255).all()  # the white gap
    assert picture[50, 10, 0] == 40 and picture[50, 150, 0] == 200  # below the labels, the images themselves


def test_a_render_of_another_size_is_an_error_not_a_stretched_picture(tmp_path: Path) -> None:
    photo, render = tmp_path / "photo.png", tmp_path / "render.png"
    cv2.imwrite(str(photo), np.zeros((60, 80, 3), np.uint8))
    cv2.imwrite(str(render), np.zeros((30, 40, 3), np.uint8))
    with pytest.raises(DemoError, match="render 40x30 does not match photo 80x60"):
        side_by_side(photo, render, tmp_path / "demo.png", "x")
    with pytest.raises(DemoError, match="cannot read"):
        side_by_side(tmp_path / "missing.png", render, tmp_path / "demo.png", "x")
