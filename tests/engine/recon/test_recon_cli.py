"""`engine reconstruct` on a capture with one corrupt photo: the photo is skipped, the warning naming it
is printed after loading and recorded in the sidecar ("capture_warnings"), and the mesh is made from
the other photos. The capture is the synthetic box room in the ScanNet layout (9 views), one PNG cut
to half its bytes as an interrupted copy leaves it; tiny settings with a seeded random network
(test_driver.py's numbers) keep the run to seconds."""

from __future__ import annotations

import json
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

