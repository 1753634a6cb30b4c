"""Training configuration: one JSON file describes data, model, crops, phases and optimiser.

A config is a plain JSON object; unknown keys are an error (typos should not silently train the
wrong thing). Relative paths are relative to the current directory (run from the repo root).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Optional

from ..errors import VortxError


@dataclass
class PhaseConfig:
    """One training phase. Phase 1: mean pooling, frozen backbone. Phase 2: softmax-with-null
    pooling (projective occupancy), backbone unfrozen except its BatchNorm parameters."""

    steps: int = 0
    lr: float = 1e-3
    batch_size: int = 2
    warmup_steps: int = 0  # linear warm-up from 1e-10 to lr (spec: 2,000 steps)
    freeze_backbone: bool = True
    use_proj_occ: bool = False  # softmax-with-null pooling (True) or masked mean (False)
    # Train only the levels' output layers (a stereo-evidence model then learns corrections to classical
    # fusion from features it cannot yet change, before the whole network moves).
    heads_only: bool = False


@dataclass
class TrainConfig:
    name: str = "vortx"
    rooms: list[str] = field(default_factory=list)  # room folders, or folders holding room folders
    model: dict[str, Any] = field(default_factory=dict)  # VortxConfig fields (incl. max_train_voxels)
    crop_size: tuple[int, int, int] = (32, 32, 24)  # fine (4 cm) voxels; must be a multiple of 4
    n_views: int = 8
    image_size: tuple[int, int] = (160, 120)  # (W, H) the images are resized to
    augment_rotate: bool = True
    augment_mirror: bool = True
    augment_photometric: bool = True
    augment_noise: float = 0.0  # max std (0-255 units) of Gaussian sensor noise, applied with p = 0.5; 0 = off
    augment_depth_scale: float = 0.1  # stereo evidence: half the maps scaled by U(1 -+ this) (FineRecon)
    phase1: PhaseConfig = field(default_factory=PhaseConfig)
    phase2: PhaseConfig = field(
        default_factory=lambda: PhaseConfig(lr=1e-4, freeze_backbone=False, use_proj_occ=True)
    )
    # Start from these trained weights (safetensors + sidecar of the same model config) instead of the
    # ImageNet trunk and zero heads: a run that goes on from an earlier run's result with new rooms.
    init_weights: str = ""
    occ_balanced: bool = False  # occupancy BCE with pos_weight n_empty/n_occupied (not in the spec)
    seed: int = 0
    out_dir: str = "runs/{name}"
    log_every: int = 1
    checkpoint_every: int = 50
    amp: bool = True  # used on CUDA only
    device: str = "auto"  # "auto", "cpu", "cuda"
    threads: int = 0  # torch.set_num_threads; 0 = leave as is
    max_minutes: float = 0.0  # stop (with a checkpoint) after this wall time; 0 = no limit
    # Learning curve: every `curve_every` steps (and at step 0) reconstruct the `curve_rooms` (held-out
    # rendered rooms) with the weights as they are and append F and the surface metrics to
    # <out_dir>/curve.jsonl (engine/train/curve.py); `curve_settings` are ReconSettings overrides.
    curve_rooms: list[str] = field(default_factory=list)
    curve_every: int = 0
    curve_settings: dict[str, Any] = field(default_factory=dict)
    base_dir: str = "."  # relative paths are resolved against this folder

    @property
    def uses_stereo(self) -> bool:
        """The model takes stereo evidence (`model.stereo_evidence` set), so crops carry stereo maps."""
        return self.model.get("stereo_evidence") is not None

    @property
    def total_steps(self) -> int:
        return self.phase1.steps + self.phase2.steps

    def phase_at(self, step: int) -> tuple[int, PhaseConfig, int]:
        """(phase number 1/2, its config, step index inside the phase) for a global step."""
        if step < self.phase1.steps:
            return 1, self.phase1, step
        return 2, self.phase2, step - self.phase1.steps

    def resolve(self, path: str) -> Path:
        p = Path(path.format(name=self.name))
        return p if p.is_absolute() else Path(self.base_dir) / p

    @property
    def out_path(self) -> Path:
        return self.resolve(self.out_dir)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("base_dir")
        return d


def _build(cls, data: dict[str, Any], where: str):
    known = {f.name: f for f in fields(cls)}
    if cls is TrainConfig and "voxel_size" in data:
        raise VortxError(f"{where}: voxel_size is not a training setting (crops use the voxel size of each room's "
                         "ground-truth TSDF, 4 cm); remove the key")
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise VortxError(f"{where}: unknown key(s) {', '.join(unknown)}; known keys: {', '.join(sorted(known))}")
    kwargs = {}
    for key, value in data.items():
        if key in ("phase1", "phase2"):
            value = _build(PhaseConfig, value, f"{where}.{key}")
        elif key in ("crop_size", "image_size"):
            value = tuple(value)
        kwargs[key] = value
    return cls(**kwargs)


def config_from_dict(data: dict[str, Any], base_dir: str | Path = ".") -> TrainConfig:
    data = dict(data)
    phases = {k: data.pop(k) for k in ("phase1", "phase2") if k in data}
    cfg = _build(TrainConfig, data, "config")
    defaults = TrainConfig()
    for key, value in phases.items():
        base = asdict(getattr(defaults, key))
        base.update(value)
        setattr(cfg, key, _build(PhaseConfig, base, f"config.{key}"))
    cfg.base_dir = str(base_dir)
    if any(c % 4 for c in cfg.crop_size):
        raise VortxError(f"config: crop_size {cfg.crop_size} must be multiples of 4 (three levels of 2x)")
    return cfg


def load_config(path: str | Path) -> TrainConfig:
    path = Path(path)
    if not path.is_file():
        raise VortxError(f"training config {path} does not exist")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise VortxError(f"training config {path} is not valid JSON: {error}") from error
    return config_from_dict(data)
