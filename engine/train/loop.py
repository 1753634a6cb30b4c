"""The training loop: two phases, Adam with linear warm-up, AMP on CUDA, exact resume, DDP.

- Phase 1: masked-mean pooling (`use_proj_occ=False`), the pretrained 2D trunk frozen (its weights
  and its BatchNorm statistics: the trunk runs in eval mode).
- Phase 2: softmax-with-null pooling (`use_proj_occ=True`), the trunk unfrozen except its
  BatchNorm layers (their parameters are not in the optimiser, their statistics stay fixed).
- Adam (default betas, no weight decay); the learning rate warms up linearly from 1e-10 over the
  phase's `warmup_steps`, then stays constant (spec section 3).
- The same code runs on CPU, one GPU, or several GPUs under `torchrun` (WORLD_SIZE set ->
  torch.distributed, DistributedDataParallel, rooms sharded per rank, rank 0 logs and saves).
- Checkpoints hold the model, optimiser, AMP scaler, step, room-sampler position and the RNG states
  of python, numpy (global and the data generator) and torch (CPU and CUDA) of every rank, so a run
  resumed from step k continues exactly as if it had never stopped.
"""

from __future__ import annotations

import json
import math
import os
import random
import time
import dataclasses
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np
from safetensors.torch import load_file
import torch
import torch.nn.functional as F
from torch import nn
import torch.distributed as tdist
from torch.nn.parallel import DistributedDataParallel as DDP

from ..errors import VortxError
from . import losses as L
from .config import PhaseConfig, TrainConfig
from ..data.room_folders import find_rooms
from ..model.config import LEVEL_NAMES, VortxConfig
from ..model.outputs import VortxBatch
from ..model.vortx import VortxNet
from ..model.weights import load_state_into, read_config, save_weights
from .batching import CropDataset, RoomSampler, TrainBatch
from .crops import CropSettings
from .curve import CURVE_FILE, curve_due, has_point, score_point

LEVELS = 3
CHECKPOINT = "checkpoint.pt"


# --------------------------------------------------------------------------------------------
# Model construction and the training forward


def build_model(cfg: TrainConfig, pretrained: bool = True):
    # The weights remember their training resolution so reconstruction feeds photos at that size.
    mcfg = VortxConfig.from_dict({"image_long_side": max(cfg.image_size), **cfg.model})
    net = VortxNet(mcfg, pretrained_backbone=pretrained and not cfg.init_weights)
    if cfg.init_weights:
        start_from_weights(net, cfg.resolve(cfg.init_weights))
    return net, mcfg


def start_from_weights(net: nn.Module, path: Path) -> None:
    """Load `path` (safetensors) into `net`; its sidecar config must describe the same network."""
    if not Path(path).is_file():
        raise VortxError(f"init_weights: {path} does not exist; give the weights.safetensors of an earlier run")
    theirs, ours = asdict(read_config(path)), asdict(net.config)
    # The pooling and the photo size are set per run and phase, not by the weights.
    differ = sorted(k for k in ours if k not in ("image_long_side", "use_proj_occ") and theirs.get(k) != ours[k])
    if differ:
        raise VortxError(f"init_weights: {path} was trained with another model ({', '.join(differ)} differ); "
                         "use the same `model` block as that run")
    load_state_into(net, load_file(str(path)), str(path))  # float16 files load into the float32 network


def set_pooling(net: nn.Module, use_proj_occ: bool) -> None:
    """Switch view pooling: softmax-with-null (True) or masked mean (False)."""
    if hasattr(net, "set_use_proj_occ"):
        net.set_use_proj_occ(use_proj_occ)
        return
    net.config = dataclasses.replace(net.config, use_proj_occ=use_proj_occ)


def trunk_modules(net: nn.Module) -> list[nn.Module]:
    return list(net.backbone.trunk_modules())


class TrainingModule(nn.Module):
    """Wraps VortxNet: forward(batch) -> dict of losses (this is what DDP wraps).

    The network's own training forward (`VortxNet.forward` over a `VortxBatch`) runs the
    coarse-to-fine pass with pruning at logit > 0 and voxel dropout (`VortxConfig.max_train_voxels`);
    the losses are computed here from its per-level predictions."""

    def __init__(self, net: nn.Module, balanced_occupancy: bool = False):
        super().__init__()
        self.net = net
        self.balanced_occupancy = balanced_occupancy
        self.last_stats: dict[str, float] = {}

    def forward(self, batch: TrainBatch) -> dict[str, torch.Tensor]:
        vb = VortxBatch(images=batch.images, K=batch.K, cam_to_world=batch.poses, origin=batch.origin,
                        crop_shape=batch.crop_size, stereo=batch.stereo, stereo_views=batch.stereo_views)
        preds = self.net(vb)
        losses: dict[str, torch.Tensor] = {}
        stats: dict[str, float] = {}
        for level, name in enumerate(LEVEL_NAMES):
            pred = preds.get(name)
            if pred is None:  # no voxel survived pruning above this level
                stats[f"voxels_{level}"] = 0.0
                continue
            if level < LEVELS - 1:
                losses[f"occ_{level}"] = L.occupancy_loss(pred.logits, pred.coords, batch.occ[level], batch.mask[level],
                                                           self.balanced_occupancy)
            else:
                losses["tsdf"] = L.tsdf_loss(pred.logits, pred.coords, batch.tsdf, batch.mask[2])
            if pred.proj_occ_logits is not None:
                losses[f"projocc_{level}"] = L.projective_occupancy_loss_batch(
                    pred.proj_occ_logits, pred.coords[:, 0], pred.pixels, pred.depth, pred.valid, batch.depths,
                    3 * pred.voxel_size)
            stats[f"voxels_{level}"] = float(len(pred.coords))
        total = sum(losses.values()) if losses else sum(p.sum() for p in self.net.parameters() if p.requires_grad) * 0.0
        losses["loss"] = total
        self.last_stats = stats
        return losses


# --------------------------------------------------------------------------------------------
# Freezing and optimiser


def bn_modules(modules) -> list[nn.Module]:
    return [m for mod in modules for m in mod.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]


def configure_phase(net: nn.Module, phase: PhaseConfig) -> list[nn.Parameter]:
    """Freeze/unfreeze for a phase; returns the parameters the optimiser must update.

    Phase with freeze_backbone: every trunk parameter is frozen. Otherwise the trunk is trainable
    except its BatchNorm layers (affine parameters frozen, never passed to the optimiser). Phase with
    heads_only: only the levels' output layers train."""
    if phase.heads_only:
        heads = {id(p) for p in net.output_layers.parameters()}
        for p in net.parameters():
            p.requires_grad_(id(p) in heads)
        set_pooling(net, phase.use_proj_occ)
        return [p for p in net.parameters() if p.requires_grad]
    trunk = trunk_modules(net)
    trunk_params = {id(p) for m in trunk for p in m.parameters()}
    trunk_bn_params = {id(p) for m in bn_modules(trunk) for p in m.parameters()}
    for p in net.parameters():
        if id(p) in trunk_params:
            p.requires_grad_(not phase.freeze_backbone and id(p) not in trunk_bn_params)
        else:
            p.requires_grad_(True)
    set_pooling(net, phase.use_proj_occ)
    return [p for p in net.parameters() if p.requires_grad]


def set_train_mode(net: nn.Module, phase: PhaseConfig) -> None:
    """net.train(), then the frozen parts in eval mode: the whole trunk when it is frozen, else
    only its BatchNorm layers (their statistics stay the pretrained ones)."""
    net.train()
    trunk = trunk_modules(net)
    for m in (trunk if phase.freeze_backbone else bn_modules(trunk)):
        m.eval()


def make_optimizer(params, phase: PhaseConfig) -> torch.optim.Optimizer:
    return torch.optim.Adam(params, lr=phase.lr)


def drop_logged_steps_after(log_path: Path, step: int) -> None:
    """Remove the log lines of steps after `step`: after a resume from the checkpoint at `step`
    they are trained again, and the log should hold each step once (the run that counts)."""
    if not log_path.is_file():
        return
    def logged_step(line: str) -> Optional[int]:
        try:
            return int(json.loads(line)["step"])
        except (ValueError, KeyError, TypeError):
            return None  # e.g. a line cut short by a crash

    lines = log_path.read_text().splitlines()
    kept = [line for line in lines if (logged := logged_step(line)) is not None and logged <= step]
    if kept != lines:
        log_path.write_text("".join(line + "\n" for line in kept))


def lr_at(phase: PhaseConfig, step_in_phase: int) -> float:
    """Linear warm-up from 1e-10 to lr over warmup_steps, then constant."""
    if phase.warmup_steps <= 0:
        return phase.lr
    frac = min(1.0, (step_in_phase + 1) / phase.warmup_steps)
    return max(1e-10, phase.lr * frac)


# --------------------------------------------------------------------------------------------
# Distributed helpers


@dataclass
class Dist:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    enabled: bool = False

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def init_distributed(device_kind: str) -> Dist:
    """torch.distributed when WORLD_SIZE is set (torchrun), else a single process."""
    if "WORLD_SIZE" not in os.environ:
        return Dist()

    world = int(os.environ["WORLD_SIZE"])
    rank = int(os.environ.get("RANK", 0))
    local = int(os.environ.get("LOCAL_RANK", 0))
    if world > 1 and not tdist.is_initialized():
        tdist.init_process_group(backend="nccl" if device_kind == "cuda" else "gloo")
    return Dist(rank, world, local, world > 1)


def choose_device(cfg: TrainConfig, dist: Dist) -> torch.device:
    kind = cfg.device
    if kind == "auto":
        kind = "cuda" if torch.cuda.is_available() else "cpu"
    if kind.startswith("cuda"):
        if not torch.cuda.is_available():
            raise VortxError("config asks for device 'cuda' but no CUDA GPU is available; set \"device\": \"cpu\"")
        torch.cuda.set_device(dist.local_rank)
        return torch.device("cuda", dist.local_rank)
    return torch.device("cpu")


# --------------------------------------------------------------------------------------------
# RNG state


def rng_state(data_rng: np.random.Generator) -> dict:
    state = {
        "python": random.getstate(),
        "numpy": _np_state_to_torch(np.random.get_state()),
        "data": json.dumps(data_rng.bit_generator.state),
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict, data_rng: np.random.Generator) -> None:
    random.setstate(_to_tuple(state["python"]))
    np.random.set_state(_np_state_from_torch(state["numpy"]))
    data_rng.bit_generator.state = json.loads(state["data"])
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def _to_tuple(x):
    return tuple(_to_tuple(v) for v in x) if isinstance(x, (list, tuple)) else x


def _np_state_to_torch(st):
    name, keys, pos, has_gauss, cached = st
    return {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
            "has_gauss": int(has_gauss), "cached": float(cached)}


def _np_state_from_torch(d):
    return (d["name"], d["keys"].numpy().astype(np.uint32), d["pos"], d["has_gauss"], d["cached"])


# --------------------------------------------------------------------------------------------
# The trainer


class Trainer:
    """Owns model, optimiser, data stream and checkpoints. `run(steps)` trains up to a global step."""

    def __init__(self, cfg: TrainConfig, dataset: Optional[CropDataset] = None, net: Optional[nn.Module] = None,
                 pretrained: bool = True, progress: bool = True, log: bool = True):
        self.cfg = cfg
        self.dist = init_distributed("cuda" if cfg.device != "cpu" and torch.cuda.is_available() else "cpu")
        self.device = choose_device(cfg, self.dist)
        if cfg.threads:
            torch.set_num_threads(cfg.threads)
        seed = cfg.seed + 1000 * self.dist.rank
        random.seed(seed)
        np.random.seed(seed % 2**32)
        torch.manual_seed(seed)
        self.data_rng = np.random.default_rng([cfg.seed, self.dist.rank])
        if dataset is None:
            rooms = find_rooms([cfg.resolve(r) for r in cfg.rooms])
            if not rooms:
                raise VortxError(f"no rooms found in {cfg.rooms}; render some with `python -m engine synth`")
            dataset = CropDataset(rooms, CropSettings(
                tuple(cfg.crop_size), cfg.n_views, cfg.augment_rotate, cfg.augment_mirror, cfg.augment_photometric,
                cfg.augment_noise, stereo=cfg.uses_stereo, depth_scale=cfg.augment_depth_scale),
                image_size=cfg.image_size)
        self.dataset = dataset
        self.sampler = RoomSampler(len(dataset), cfg.seed, self.dist.rank, self.dist.world_size)
        if net is None:
            torch.manual_seed(cfg.seed)  # identical initial weights on every rank
            net, _ = build_model(cfg, pretrained=pretrained)
        self.net = net.to(self.device)
        self.module = TrainingModule(self.net, cfg.occ_balanced)
        self.step = 0
        self.phase_no = 0
        self.optimizer: Optional[torch.optim.Optimizer] = None
        self.ddp: Optional[nn.Module] = None
        self.use_amp = cfg.amp and self.device.type == "cuda"
        self.scaler = torch.amp.GradScaler("cuda", enabled=self.use_amp)
        self.show_progress = progress and self.dist.is_main
        self.log_enabled = log and self.dist.is_main
        self.checkpointing = log
        self.out = cfg.out_path
        self.history: list[dict] = []

    # -- phases ------------------------------------------------------------------------------
    def _enter_phase(self, phase_no: int) -> None:
        phase = self.cfg.phase1 if phase_no == 1 else self.cfg.phase2
        params = configure_phase(self.net, phase)
        self.optimizer = make_optimizer(params, phase)
        self.phase_no = phase_no
        if self.dist.enabled:
            ids = [self.device.index] if self.device.type == "cuda" else None
            self.ddp = DDP(self.module, device_ids=ids, find_unused_parameters=True)
        else:
            self.ddp = self.module

    # -- one step ----------------------------------------------------------------------------
    def next_batch(self, batch_size: int) -> TrainBatch:
        ids = [self.sampler.next() for _ in range(batch_size)]
        return self.dataset.batch(ids, self.data_rng).to(self.device)

    def train_step(self) -> dict[str, float]:
        phase_no, phase, k = self.cfg.phase_at(self.step)
        if phase_no != self.phase_no or self.optimizer is None:
            self._enter_phase(phase_no)
        set_train_mode(self.net, phase)
        lr = lr_at(phase, k)
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        t0 = time.perf_counter()
        batch = self.next_batch(phase.batch_size)
        with torch.autocast("cuda", dtype=torch.float16, enabled=self.use_amp):
            losses = self.ddp(batch)
        self.optimizer.zero_grad(set_to_none=True)
        self.scaler.scale(losses["loss"]).backward()
        self.scaler.step(self.optimizer)
        self.scaler.update()
        self.step += 1
        rec = {"step": self.step, "phase": phase_no, "lr": lr, "time_s": round(time.perf_counter() - t0, 3)}
        rec.update({k: float(v.detach()) for k, v in losses.items()})
        rec.update(getattr(self.module, "last_stats", {}))
        rec["rooms"] = [i.get("room") for i in batch.info]
        return rec

    def run(self, until: Optional[int] = None, max_minutes: Optional[float] = None,
            on_step: Optional[Callable[[dict], None]] = None) -> list[dict]:
        until = self.cfg.total_steps if until is None else until
        max_minutes = self.cfg.max_minutes if max_minutes is None else max_minutes
        start = time.time()
        bar = None
        if self.show_progress:
            from tqdm import tqdm  # defers tqdm: only the command line's progress bar

            bar = tqdm(total=until, initial=self.step, desc=self.cfg.name, dynamic_ncols=True)
        log = None
        if self.log_enabled:
            self.out.mkdir(parents=True, exist_ok=True)
            drop_logged_steps_after(self.out / "losses.jsonl", self.step)
            drop_logged_steps_after(self.out / CURVE_FILE, self.step)
            log = open(self.out / "losses.jsonl", "a")
        records = []
        try:
            if self.log_enabled and curve_due(self.cfg, self.step) and not has_point(self.out / CURVE_FILE, self.step):
                self._curve_point()
            while self.step < until:
                rec = self.train_step()
                if not math.isfinite(rec["loss"]):
                    raise VortxError(f"training diverged at step {self.step}: loss {rec['loss']}")
                rec["wall_s"] = round(time.time() - start, 1)
                records.append(rec)
                if log and (self.step % self.cfg.log_every == 0 or self.step == until):
                    log.write(json.dumps(rec) + "\n")
                    log.flush()
                if bar:
                    bar.update(1)
                    bar.set_postfix(phase=rec["phase"], loss=f"{rec['loss']:.3f}")
                if on_step:
                    on_step(rec)
                if self.log_enabled and curve_due(self.cfg, self.step):
                    self._curve_point()
                timed_out = self._agree(bool(max_minutes) and (time.time() - start) > 60 * max_minutes)
                # Every rank takes part in a checkpoint (it gathers their RNG and sampler states); only
                # the main rank writes it.
                if self.checkpointing and (self.step % self.cfg.checkpoint_every == 0 or self.step == until or timed_out):
                    self.save_checkpoint(self.out / CHECKPOINT)
                if timed_out:
                    break
        finally:
            if bar:
                bar.close()
            if log:
                log.close()
        self.history.extend(records)
        return records

    def _curve_point(self) -> None:
        """A learning-curve point (engine/train/curve.py); its time does not count as step time. A point
        that fails (a held-out room unreadable, a reconstruction error) is reported and skipped: hours of
        training are not lost to an evaluation."""
        t0 = time.time()
        try:
            lines = score_point(self.net, self.cfg, self.step, self.out)
        except Exception as error:  # noqa: BLE001 - any failure of the evaluation, never of the training
            print(f"curve at step {self.step} failed, training goes on: {type(error).__name__}: {error}", flush=True)
            return
        summary = ", ".join(f"{l['method']} F {l['fscore']:.3f} normals {l['normal_agreement']:.3f} "
                            f"floaters {l['floater_share']:.3f}" for l in lines)
        print(f"curve at step {self.step}: {summary} ({time.time() - t0:.0f} s)", flush=True)

    def _agree(self, flag: bool) -> bool:
        """True on every rank when it is True on any (ranks must stop at the same step, or the
        ones still training wait forever for the others' gradients)."""
        if not self.dist.enabled:
            return flag

        value = torch.tensor([1.0 if flag else 0.0], device=self.device)
        tdist.all_reduce(value, op=tdist.ReduceOp.MAX)
        return bool(value.item() > 0)

    # -- checkpoints ---------------------------------------------------------------------------
    def state_dict(self) -> dict:
        rng = rng_state(self.data_rng)
        if self.dist.enabled:
            all_rng = [None] * self.dist.world_size
            tdist.all_gather_object(all_rng, rng)
            all_samplers = [None] * self.dist.world_size
            tdist.all_gather_object(all_samplers, self.sampler.state_dict())
        else:
            all_rng, all_samplers = [rng], [self.sampler.state_dict()]
        return {
            "version": 1,
            "step": self.step,
            "phase": self.phase_no,
            "model": self.net.state_dict(),
            "model_config": json.dumps(self.net.config.to_dict()),
            "optimizer": self.optimizer.state_dict() if self.optimizer else None,
            "scaler": self.scaler.state_dict(),
            "sampler": all_samplers,
            "rng": all_rng,
            "train_config": json.dumps(self.cfg.to_dict()),
        }

    def save_checkpoint(self, path: Path) -> None:
        state = self.state_dict()
        if not self.dist.is_main:
            return
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        torch.save(state, tmp)
        tmp.replace(path)

    def load_checkpoint(self, path: Path) -> None:
        path = Path(path)
        if not path.is_file():
            raise VortxError(f"cannot resume: {path} does not exist")
        state = torch.load(path, map_location=self.device, weights_only=True)
        self.net.load_state_dict(state["model"])
        self.step = int(state["step"])
        if state["phase"]:
            self._enter_phase(int(state["phase"]))
            if state["optimizer"] is not None:
                self.optimizer.load_state_dict(state["optimizer"])
        self.scaler.load_state_dict(state["scaler"])
        r = self.dist.rank if len(state["rng"]) > self.dist.rank else 0
        self.sampler.load_state_dict(state["sampler"][r])
        set_rng_state(state["rng"][r], self.data_rng)

    # -- export --------------------------------------------------------------------------------
    def export_weights(self, path: Path) -> Path:
        """Save the trained network as safetensors + JSON config for `reconstruct` (inference uses
        softmax-with-null pooling when the model was trained with it)."""
        final_phase = self.cfg.phase2 if self.cfg.phase2.steps > 0 else self.cfg.phase1
        set_pooling(self.net, final_phase.use_proj_occ)
        self.net.eval()
        save_weights(self.net, self.net.config, path)
        return Path(path)
