"""`engine reconstruct` on a capture with one corrupt photo: the photo is skipped, the warning naming it
is printed after loading and recorded in the sidecar ("capture_warnings"), and the mesh is made from
the other photos. The capture is the synthetic box room in the ScanNet layout (9 views), one PNG cut
to half its bytes as an interrupted copy leaves it; tiny settings with a seeded random network
(test_driver.py's numbers) keep the run to seconds. A textured result whose atlas step crashes (xatlas's
worker process segfaulting, forced) fails with the step named and keeps the PLY written before it."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from engine.__main__ import main
from engine.recon.synthetic import make_synthetic_capture

TINY = ["--method", "vortx", "--weights", "random", "--voxel-size", "0.16", "--tile-size", "8", "--views", "3", "--image-size", "160",
        "--colour-views", "3", "--max-room-size", "2", "2", "2", "--quiet"]


@pytest.fixture(scope="module")
def capture_with_a_corrupt_photo(tmp_path_factory) -> tuple[Path, str]:
    folder = tmp_path_factory.mktemp("corrupt") / "room"
    make_synthetic_capture(folder, room_size=(3.0, 3.0, 2.5), frames=9, image_size=(160, 120))
    photos = sorted((folder / "color").iterdir())
    bad = photos[4]
    data = bad.read_bytes()
    bad.write_bytes(data[: len(data) // 2])
    return folder, bad.name


def test_reconstruct_skips_a_corrupt_photo_and_says_so(capture_with_a_corrupt_photo, tmp_path, capsys):
    folder, bad = capture_with_a_corrupt_photo
    mesh = tmp_path / "room.ply"
    assert main(["reconstruct", str(folder), "--out", str(mesh), *TINY]) == 0
    err = capsys.readouterr().err
    warning = next(line for line in err.splitlines() if bad in line)
    assert warning.startswith("warning: 1 photo(s) skipped") and "truncated" in warning
    # Printed after loading, before preparation reports what it did with the poses.
    assert err.index(warning) < err.index("poses: metric capture")

    sidecar = json.loads(mesh.with_suffix(".json").read_text())
    (recorded,) = [w for w in sidecar["capture_warnings"] if bad in w]
    assert recorded == warning.removeprefix("warning: ")
    assert sidecar["poses"]["source"] == "given" and sidecar["poses"]["scale_source"] == "metric capture"
    assert not sidecar["poses"]["refined"]
    assert mesh.stat().st_size > 0


def test_a_crashing_atlas_fails_the_textured_result_and_keeps_the_ply(capture_with_a_corrupt_photo, tmp_path, capsys,
                                                                       monkeypatch):
    import fixtures_native
    from engine.mesh_io import read_ply
    from engine.texture import atlas

    folder, _ = capture_with_a_corrupt_photo
    glb = tmp_path / "room.glb"
    monkeypatch.setattr(atlas, "xatlas_layout", fixtures_native.segfault)
    assert main(["reconstruct", str(folder), "--out", str(glb), *TINY, "--texture-size", "512", "--face-budget", "300"]) == 1
    err = capsys.readouterr().err
    assert "error: texture atlas (xatlas) crashed on each of 2 tries: its worker process was killed by SIGSEGV" in err
    assert f"(the untextured mesh is in {glb.with_suffix('.ply')})" in err
    shutil.rmtree(re.search(r"kept in (\S+) for a bug report", err)[1])
    assert not glb.exists() and len(read_ply(glb.with_suffix(".ply")).faces) > 0  # this process lived on to say so


def test_refine_and_keep_poses_together_are_refused_before_anything_runs(tmp_path, capsys):
    code = main(["reconstruct", str(tmp_path / "no-such-capture"), "--out", str(tmp_path / "room.ply"),
                 "--refine-poses", "--keep-poses", "--quiet"])
    assert code != 0
    err = capsys.readouterr().err
    assert "--refine-poses and --keep-poses contradict each other" in err
    assert not (tmp_path / "room.ply").exists()


def test_poses_found_off_are_refined_unless_keep_poses(capture_with_a_corrupt_photo, tmp_path, monkeypatch):
    import engine.poses.prepare as prepare

    seen = []
    real_prepare = prepare.prepare_capture

    def recording_prepare(capture, *args, **kwargs):
        seen.append(kwargs.get("refine_when_off"))
        return real_prepare(capture, *args, **{**kwargs, "check_poses": False})  # no COLMAP here: only the wiring

    monkeypatch.setattr("engine.recon.cli.prepare_capture", recording_prepare)
    folder, _ = capture_with_a_corrupt_photo
    assert main(["reconstruct", str(folder), "--out", str(tmp_path / "a.ply"), *TINY]) == 0
    assert main(["reconstruct", str(folder), "--out", str(tmp_path / "b.ply"), *TINY, "--keep-poses"]) == 0
    assert seen == [True, False]
