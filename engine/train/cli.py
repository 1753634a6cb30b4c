"""`python -m engine train CONFIG [--resume] [--precompute-only] [--export PATH]`.

Trains VoRTX from a JSON config (see engine/train/config.py and configs/). Progress goes to a tqdm
bar; every step's losses go to `<out_dir>/losses.jsonl`; checkpoints to `<out_dir>/checkpoint.pt`;
the final weights to `<out_dir>/weights.safetensors` (+ `.json` config). Rooms without their
ground-truth TSDF (`tsdf_gt_04.npz`) get it fused first. Multi-GPU: `torchrun --nproc_per_node N
-m engine train CONFIG`.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import time

from ..errors import VortxError
from .config import load_config


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="training config (JSON), e.g. configs/train_default.json")
    parser.add_argument("--resume", action="store_true", help="continue from <out_dir>/checkpoint.pt exactly")
    parser.add_argument("--precompute-only", action="store_true", help="only fuse the missing ground-truth TSDFs")
    parser.add_argument("--steps", type=int, default=None, help="stop at this global step (default: the config's total)")
    parser.add_argument("--export", default=None, help="where to write the final weights (.safetensors)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    # defers torch (rooms and the trainer load it): `engine train --help` and bad arguments answer at once
    from ..data.room_folders import find_rooms, gt_path, precompute_room
    from .loop import CHECKPOINT, Trainer

    cfg = load_config(args.config)
    rooms = find_rooms([cfg.resolve(r) for r in cfg.rooms])
    if not rooms:
        raise VortxError(f"no rooms found in {cfg.rooms}; render some with `python -m engine synth --rooms N --out DIR`")

    if int(os.environ.get("RANK", "0")) == 0:
        for i, room in enumerate(rooms):
            if gt_path(room) is None:
                print(f"fusing ground truth {i + 1}/{len(rooms)}: {room}", flush=True)
            precompute_room(room)
    if args.precompute_only:
        return 0
    trainer = Trainer(cfg, progress=not args.no_progress)
    trainer.out.mkdir(parents=True, exist_ok=True)
    if trainer.dist.is_main:
        (trainer.out / "train_config.json").write_text(json.dumps(cfg.to_dict(), indent=2))
    if args.resume:
        trainer.load_checkpoint(trainer.out / CHECKPOINT)
        print(f"resumed at step {trainer.step}", flush=True)

    start = time.time()
    records = trainer.run(until=args.steps)
    if trainer.dist.is_main:
        summary = {"steps": trainer.step, "total_steps": cfg.total_steps, "wall_s_this_run": round(time.time() - start, 1),
                   "step_s_mean": round(float(sum(r["time_s"] for r in records) / max(len(records), 1)), 3),
                   "rooms": [str(r) for r in rooms], "torch_threads": __import__("torch").get_num_threads(),
                   "device": str(trainer.device), "world_size": trainer.dist.world_size}
        (trainer.out / "train_summary.json").write_text(json.dumps(summary, indent=2))
        if trainer.step < cfg.total_steps:
            reason = f"--steps {args.steps}" if args.steps is not None and trainer.step >= args.steps else \
                f"max_minutes {cfg.max_minutes}"
            print(f"stopped at step {trainer.step} of {cfg.total_steps} ({reason}); weights exported as they are; "
                  "--resume continues", flush=True)
        path = Path(args.export) if args.export else trainer.out / "weights.safetensors"
        trainer.export_weights(path)
        print(f"weights: {path}", flush=True)
    return 0
