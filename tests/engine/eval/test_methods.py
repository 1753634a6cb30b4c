"""`engine eval-methods`: each method spec becomes the reconstruction settings it names, every method is
scored by the same held-out evaluation, and the room box once."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.errors import VortxError
from engine.eval import heldout
from engine.eval.methods import evaluate_methods, parse_method, per_room_table


def test_method_specs() -> None:
    assert parse_method("stereo fusion=stereo") == ("stereo fusion", {"method": "stereo", "weights": None})
    assert parse_method("v2=vortx:weights/v.safetensors") == ("v2", {"method": "vortx", "weights": "weights/v.safetensors"})
    for bad in ("stereo", "x=vortx", "x=colmap", "=stereo", "x=stereo:w.safetensors"):
        with pytest.raises(VortxError, match="LABEL=stereo"):
            parse_method(bad)


def test_each_method_runs_with_its_own_settings_and_the_box_once(monkeypatch, tmp_path: Path) -> None:
    calls = []

    def fake_evaluate_rooms(rooms, weights, recon_overrides=None, out_dir=None, box=True):
        calls.append((dict(weights), dict(recon_overrides), box, out_dir))
        labels = list(weights) + (["room box"] if box else [])
        score = {"stereo": 0.7, "vortx": 0.1}.get(recon_overrides.get("method"), 0.6)
        per_room = {label: {room.name: {"fscore": score} for room in rooms} for label in labels}
        return {"per_room": per_room, "mean": {label: {"fscore": score} for label in labels}}

    monkeypatch.setattr(heldout, "evaluate_rooms", fake_evaluate_rooms)
    rooms = [Path("room_01000"), Path("room_01001")]
    methods = dict(map(parse_method, ["stereo fusion=stereo", "VoRTX v2=vortx:v2.safetensors"]))
    result = evaluate_methods(rooms, methods, {"views": 12}, out_dir=tmp_path)
    assert calls == [
        ({"stereo fusion": None}, {"views": 12, "method": "stereo"}, False, tmp_path / "stereo_fusion"),
        ({"VoRTX v2": "v2.safetensors"}, {"views": 12, "method": "vortx"}, False, tmp_path / "VoRTX_v2"),
        ({}, {"views": 12}, True, tmp_path / "room_box"),
    ]
    assert list(result["mean"]) == ["stereo fusion", "VoRTX v2", "room box"]
    assert result["mean"]["stereo fusion"]["fscore"] == 0.7 and result["mean"]["VoRTX v2"]["fscore"] == 0.1
    table = per_room_table(result)
    assert table.splitlines()[0] == "| room | stereo fusion | VoRTX v2 | room box |"
    assert "| room_01001 | 0.700 | 0.100 | 0.600 |" in table
