"""`engine eval-weights` (engine/eval/heldout.py): the surface metrics per room, as means and in its table.

The reconstruction is replaced by a known mesh (the true room plus a floating 20 cm square), so the
numbers are hand-computable and the test needs no network and no stereo run.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

import engine.recon
from engine.__main__ import main as engine_main
from engine.eval import box_mesh
from engine.mesh_io import Mesh, write_ply
from fixtures_capture import write_room_scene
from fixtures_rooms import box_room

ROOM_SIZE = (3.0, 2.6, 2.4)


def with_floater(mesh: Mesh) -> Mesh:
    square = np.array([[1.0, 1.0, 1.2], [1.2, 1.0, 1.2], [1.2, 1.2, 1.2], [1.0, 1.2, 1.2]], np.float32)
    n = len(mesh.vertices)
    return Mesh(np.concatenate([mesh.vertices, square]),
                np.concatenate([mesh.faces, np.array([[n, n + 1, n + 2], [n, n + 2, n + 3]], np.int32)]))


def test_eval_weights_reports_surface_metrics_per_room_and_as_means(tmp_path, monkeypatch, capsys):
    room = write_room_scene(tmp_path / "rooms" / "box", box_room(size=ROOM_SIZE, n_frames=8, image_size=(64, 48)))
    truth = box_mesh(np.zeros(3), np.array(ROOM_SIZE))
    write_ply(room / "mesh_gt.ply", truth.vertices, truth.faces)
    predicted = with_floater(truth)
    monkeypatch.setattr(engine.recon, "reconstruct", lambda capture, settings: SimpleNamespace(mesh=predicted))

    out = tmp_path / "eval"
    assert engine_main(["eval-weights", "--rooms", str(tmp_path / "rooms"), "--weights", "known=stereo",
                        "--out", str(out)]) == 0
    result = json.loads((out / "metrics.json").read_text())
    known = result["per_room"]["known"]["box"]
    assert known["pieces"] == 2  # the room and the floating square
    room_area = 2 * (3.0 * 2.6 + 3.0 * 2.4 + 2.6 * 2.4)  # the closed box: no open edge
    assert known["floater_share"] == pytest.approx(0.04 / (room_area + 0.04))
    assert known["boundary_per_m2"] == pytest.approx(0.8 / (room_area + 0.04))  # the square's rim
    assert known["normal_agreement"] > 0.95
    assert result["mean"]["known"]["pieces"] == 2 and "normal_agreement" in result["mean"]["room box"]
    printed = capsys.readouterr().out
    assert "box known: F" in printed and "floaters" in printed  # the per-room line
    table = [line for line in printed.splitlines() if line.startswith("| method")][0]
    for heading in ("normals", "floaters", "pieces", "area ratio", "boundary m/m2"):
        assert heading in table
