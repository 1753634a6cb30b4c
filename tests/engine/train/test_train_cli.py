"""`python -m engine train CONFIG` as a user runs it: ground truth fused on first use, a stop at
--steps that says how to go on, --resume to the end, the loss log and the exported weights."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from engine.__main__ import main as engine_main
from engine.model.weights import load_weights
from fixtures_rooms import box_room
from fixtures_capture import write_room_scene


def test_train_stops_at_steps_then_resumes_to_the_end(tmp_path: Path, capsys) -> None:
    write_room_scene(tmp_path / "rooms" / "box", box_room(n_frames=8, image_size=(64, 48)))
    tiny = json.loads((Path(__file__).resolve().parents[3] / "configs" / "train_tiny.json").read_text())
    tiny |= {"rooms": [str(tmp_path / "rooms")], "out_dir": str(tmp_path / "runs" / "{name}"), "max_minutes": 0}
    config = tmp_path / "tiny.json"
    config.write_text(json.dumps(tiny))
    total = tiny["phase1"]["steps"] + tiny["phase2"]["steps"]
    torch.set_num_threads(1)

    assert engine_main(["train", str(config), "--steps", "3", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert f"stopped at step 3 of {total} (--steps 3)" in out and "--resume continues" in out
    assert (tmp_path / "rooms" / "box" / "tsdf_gt_04.npz").is_file()  # fused once, kept beside the room

    assert engine_main(["train", str(config), "--resume", "--no-progress"]) == 0
    assert "stopped at step" not in capsys.readouterr().out
    run = tmp_path / "runs" / "tiny"
    log = [json.loads(line) for line in (run / "losses.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == list(range(1, total + 1))
    assert {r["phase"] for r in log} == {1, 2} and all(r["loss"] > 0 for r in log)
    model, loaded = load_weights(run / "weights.safetensors")
    assert loaded.feature_channels == tuple(tiny["model"]["feature_channels"]) and not model.training
