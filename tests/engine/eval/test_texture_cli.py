"""`engine eval-texture`: which photos it holds out, and the errors a user reads. (The measurement
itself is tested in test_texture_views.py and runs end to end in `make demo`.)"""

from __future__ import annotations

import pytest

from engine.__main__ import main
from engine.errors import VortxError
from engine.eval.texture_views import report_table, spread_heldout


def test_held_out_photos_are_spread_over_the_walk():
    stems = [f"{i:06d}" for i in range(36)]
    assert spread_heldout(list(reversed(stems)), 4) == ["000004", "000013", "000022", "000031"]
    with pytest.raises(VortxError, match="keep at least one to bake from"):
        spread_heldout(stems[:3], 3)


def test_report_table_has_a_row_per_photo_and_the_mean():
    view = {"photo": "a.jpg", "pixels": 10, "psnr": {"vertex colours": 20.0, "texture": 25.5},
            "ssim": {"vertex colours": 0.5, "texture": 0.75}}
    lines = report_table({"views": [view], "mean": {"psnr": view["psnr"], "ssim": view["ssim"]}})
    assert len(lines) == 3 and "texture" in lines[0]
    assert "25.50 / 0.750" in lines[1] and lines[2].startswith("mean")


def test_meshes_must_be_ply_files(tmp_path, capsys):
    assert main(["eval-texture", str(tmp_path), str(tmp_path / "room.obj")]) == 1
    assert "give meshes as .ply files" in capsys.readouterr().err
