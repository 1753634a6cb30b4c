"""`python -m engine train CONFIG` as a user runs it: ground truth fused on first use, a stop at
--steps that says how to go on, --resume to the end, the loss log and the exported weights."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
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


def test_a_killed_run_resumes_from_its_last_checkpoint_with_the_same_losses(tmp_path: Path) -> None:
    """A training process killed without warning (SIGKILL: no handler runs) continues with --resume from its
    last checkpoint: every step is logged once and the losses are those of a run never interrupted."""
    import os
    import signal
    import subprocess
    import sys
    import time

    write_room_scene(tmp_path / "rooms" / "box", box_room(n_frames=8, image_size=(64, 48)))
    tiny = json.loads((Path(__file__).resolve().parents[3] / "configs" / "train_tiny.json").read_text())
    tiny |= {"rooms": [str(tmp_path / "rooms")], "max_minutes": 0, "checkpoint_every": 3}
    tiny["phase1"]["steps"], tiny["phase2"]["steps"] = 10, 6
    total = 16
    logs = {}
    for name in ("straight", "killed"):
        config = tmp_path / f"{name}.json"
        config.write_text(json.dumps(tiny | {"name": name, "out_dir": str(tmp_path / "runs" / "{name}")}))
        logs[name] = tmp_path / "runs" / name / "losses.jsonl"
        command = [sys.executable, "-m", "engine", "train", str(config), "--no-progress"]
        repo = Path(__file__).resolve().parents[3]
        if name == "straight":
            subprocess.run(command, cwd=repo, check=True, capture_output=True)
            continue
        process = subprocess.Popen(command, cwd=repo, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.time() + 300
        while time.time() < deadline and process.poll() is None:
            if logs[name].is_file() and len(logs[name].read_text().splitlines()) >= 5:
                break
            time.sleep(0.02)
        assert process.poll() is None, "the run ended before it could be killed"
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
        killed_at = len(logs[name].read_text().splitlines())
        assert 5 <= killed_at < total
        subprocess.run(command + ["--resume"], cwd=repo, check=True, capture_output=True)
    straight = [json.loads(line) for line in logs["straight"].read_text().splitlines()]
    resumed = [json.loads(line) for line in logs["killed"].read_text().splitlines()]
    assert [r["step"] for r in resumed] == list(range(1, total + 1))
    for a, b in zip(straight, resumed):
        assert b["loss"] == pytest.approx(a["loss"], rel=1e-4, abs=1e-6), a["step"]
