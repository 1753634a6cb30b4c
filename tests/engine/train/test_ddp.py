"""Multi-process training (torch DDP through torchrun, gloo backend on CPU): the ranks stay in
step, share their gradients, train on different rooms, checkpoint together and resume exactly."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

WORKER = Path(__file__).resolve().parents[2] / "ddp_worker.py"
REPO = Path(__file__).resolve().parents[3]


def _torchrun(out: Path, steps: int, resume: bool = False) -> list[dict]:
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
           str(WORKER), str(out), str(steps)] + (["--resume"] if resume else [])
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    # A rank left waiting for the other (a collective only one of them calls) hangs for ever; the
    # timeout turns that into a failure.
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return [torch.load(out / f"rank{r}.pt", weights_only=True) for r in (0, 1)]


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    out = tmp_path_factory.mktemp("ddp_straight")
    return out, _torchrun(out, 4)


def test_ranks_train_different_rooms_into_identical_weights(straight):
    out, (rank0, rank1) = straight
    assert rank0["world_size"] == rank1["world_size"] == 2
    # the room stream is sharded: each epoch's permutation of the two rooms is split between the
    # ranks, so at every step they train on different rooms
    assert len(rank0["rooms"]) == len(rank1["rooms"]) == 4
    assert all(a != b for a, b in zip(rank0["rooms"], rank1["rooms"]))
    # gradients are all-reduced, so both ranks hold the same network after every step
    for key, value in rank0["weights"].items():
        if value.is_floating_point() and "running_" not in key:
            assert torch.equal(value, rank1["weights"][key]), key
    log = (out / "losses.jsonl").read_text().splitlines()
    assert len(log) == 4  # only rank 0 writes the log


def test_resume_from_a_ddp_checkpoint_is_exact(straight, tmp_path):
    _, (full, _) = straight
    _torchrun(tmp_path, 2)
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 2 and len(ckpt["sampler"]) == 2 and len(ckpt["rng"]) == 2
    resumed, _ = _torchrun(tmp_path, 4, resume=True)
    for key, value in full["weights"].items():
        assert torch.equal(value, resumed["weights"][key]), key
