"""One rank of the DDP test in test_train_ddp.py; run by torchrun (gloo on CPU).

usage: ddp_worker.py OUT_DIR STEPS [--resume]. Trains the tiny box-room setup of test_train_loop to
global step STEPS, then writes rank<r>.pt: that rank's final weights and the rooms it trained on."""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from engine.train.config import config_from_dict
from engine.train.batching import CropDataset
from engine.train.crops import CropSettings
from engine.train.loop import CHECKPOINT, Trainer
from fixtures_rooms import box_room


def main(out_dir: str, steps: int, resume: bool) -> None:
    torch.set_num_threads(1)
    cfg = config_from_dict({
        "name": "ddp", "model": {"feature_channels": [8, 8, 8], "unet_base_widths": [4, 4, 4],
                                 "max_train_voxels": [2048, 4096]},
        "crop_size": [32, 32, 16], "n_views": 3, "image_size": [64, 48],
        "phase1": {"steps": 2, "batch_size": 1, "lr": 1e-3, "warmup_steps": 1},
        "phase2": {"steps": 2, "batch_size": 1, "lr": 1e-4},
        "out_dir": out_dir, "checkpoint_every": 1, "seed": 3,
    })
    rooms = [box_room(n_frames=8, image_size=(64, 48), seed=s) for s in (0, 1)]
    dataset = CropDataset(rooms, CropSettings(tuple(cfg.crop_size), cfg.n_views), image_size=cfg.image_size)
    trainer = Trainer(cfg, dataset=dataset, pretrained=False, progress=False, log=True)
    if resume:
        trainer.load_checkpoint(Path(out_dir) / CHECKPOINT)
    records = trainer.run(steps)
    torch.save({"weights": trainer.net.state_dict(), "rooms": [room for r in records for room in r["rooms"]],
                "world_size": trainer.dist.world_size},
               Path(out_dir) / f"rank{trainer.dist.rank}.pt")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), "--resume" in sys.argv[3:])
