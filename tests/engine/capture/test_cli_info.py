"""`python -m engine info`."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from engine.__main__ import main
from conftest import REPO
from fixtures_capture import intrinsics, ring_poses, write_photo_folder, write_scannet


def test_info_text_for_a_scannet_capture(tmp_path, capsys):
    write_scannet(tmp_path, ring_poses(3), intrinsics(55.0, 64, 48), (64, 48))
    np.savetxt(tmp_path / "pose" / "2.txt", np.full((4, 4), np.inf))
    assert main(["info", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "format      scannet" in out
    assert "frames      2" in out and "resolution  64 x 48" in out and "poses       2 of 2 frames" in out
    assert "fx 55.00" in out and "metric      yes" in out and "depth       2 of 2 frames" in out
    assert "warnings    1" in out and "2.txt" in out


def test_info_json_for_a_photo_folder(tmp_path, capsys):
    write_photo_folder(tmp_path, 3, (40, 30))
    assert main(["info", str(tmp_path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["format"] == "images" and summary["frames"] == 3
    assert (summary["width"], summary["height"]) == (40, 30)
    assert summary["posed_frames"] == 0 and summary["frames_with_intrinsics"] == 0 and summary["intrinsics"] is None
    assert summary["metric"] is False and summary["warnings"] == []


def test_info_bad_input_exits_1_with_error(tmp_path, capsys):
    assert main(["info", str(tmp_path / "missing")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: capture not found") and "missing" in err


def test_info_runs_as_a_module_without_importing_torch(tmp_path):
    write_photo_folder(tmp_path, 2)
    code = ("import sys, runpy; sys.argv = ['engine', 'info', sys.argv[1]]\n"
            "try:\n    runpy.run_module('engine', run_name='__main__')\n"
            "except SystemExit as e:\n    assert e.code == 0, e.code\n"
            "assert 'torch' not in sys.modules and 'pycolmap' not in sys.modules, 'heavy import'\n")
    result = subprocess.run([sys.executable, "-c", code, str(tmp_path)], cwd=REPO, capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    assert "format      images" in result.stdout
