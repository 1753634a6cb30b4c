"""Batches of training crops: the batch type, collation, the resumable room sampler and the dataset
that loads rooms lazily and cuts crops from them."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch

from ..errors import VortxError
from .crops import CropSample, CropSettings, make_crop
from .rooms import RoomData, load_room


@dataclass
class TrainBatch:
    """A batch of B crops with V views each (all crops share crop_size and image size).

    images (B, V, 3, H, W) RGB 0-255; depths (B, V, H, W) metres; K (B, V, 3, 3); poses (B, V, 4, 4)
    camera-to-crop-frame; origin (B, 3); crop_size (X, Y, Z) fine voxels; voxel_size (fine);
    tsdf (B, X, Y, Z) fine targets; occ[l] (B, X_l, Y_l, Z_l) for l = 0 coarse, 1 medium;
    mask[l] for l = 0, 1, 2 (bool, supervised); stereo (per crop, StereoEvidence) and stereo_views
    (B, V) when the model takes stereo evidence."""

    images: torch.Tensor
    depths: torch.Tensor
    K: torch.Tensor
    poses: torch.Tensor
    origin: torch.Tensor
    crop_size: tuple[int, int, int]
    voxel_size: float
    tsdf: torch.Tensor
    occ: list[torch.Tensor]
    mask: list[torch.Tensor]
    info: list[dict] = field(default_factory=list)
    stereo: Optional[list] = None
    stereo_views: Optional[torch.Tensor] = None

    @property
    def batch_size(self) -> int:
        return self.images.shape[0]

    def to(self, device) -> "TrainBatch":
        mv = lambda t: t.to(device, non_blocking=True)  # noqa: E731
        return TrainBatch(
            mv(self.images), mv(self.depths), mv(self.K), mv(self.poses), mv(self.origin), self.crop_size,
            self.voxel_size, mv(self.tsdf), [mv(o) for o in self.occ], [mv(m) for m in self.mask], self.info,
            None if self.stereo is None else [e.to(device) for e in self.stereo],
            None if self.stereo_views is None else mv(self.stereo_views),
        )


def collate(samples: Sequence[CropSample], crop_size: Sequence[int]) -> TrainBatch:
    """Stack crops of one crop_size and image size (all from rooms of one voxel size)."""
    voxel_sizes = {s.voxel_size for s in samples}
    if len(voxel_sizes) != 1:
        raise VortxError(f"a batch mixes rooms with different ground-truth voxel sizes {sorted(voxel_sizes)}")
    return TrainBatch(
        images=torch.stack([s.images for s in samples]),
        depths=torch.stack([s.depths for s in samples]),
        K=torch.stack([s.K for s in samples]),
        poses=torch.stack([s.poses for s in samples]),
        origin=torch.stack([s.origin for s in samples]),
        crop_size=tuple(crop_size),
        voxel_size=voxel_sizes.pop(),
        tsdf=torch.stack([s.targets.tsdf for s in samples]),
        occ=[torch.stack([s.targets.occ[l] for s in samples]) for l in range(2)],
        mask=[torch.stack([s.targets.mask[l] for s in samples]) for l in range(3)],
        info=[s.info for s in samples],
        stereo=[s.stereo for s in samples] if samples[0].stereo is not None else None,
        stereo_views=torch.stack([s.stereo_views for s in samples]) if samples[0].stereo is not None else None,
    )


class RoomSampler:
    """Infinite, resumable stream of room indices for one rank (DistributedSampler-like): each
    epoch is a seeded permutation of all rooms, padded to a multiple of world_size and sharded
    as perm[rank::world_size]. The position is (epoch, index) and goes into checkpoints."""

    def __init__(self, n_rooms: int, seed: int = 0, rank: int = 0, world_size: int = 1):
        if n_rooms <= 0:
            raise VortxError("no training rooms")
        self.n_rooms, self.seed, self.rank, self.world_size = n_rooms, seed, rank, world_size
        self.epoch, self.index = 0, 0

    def _shard(self, epoch: int) -> np.ndarray:
        perm = np.random.default_rng([self.seed, epoch]).permutation(self.n_rooms)
        pad = (-len(perm)) % self.world_size
        perm = np.concatenate([perm, perm[:pad]])
        return perm[self.rank :: self.world_size]

    def next(self) -> int:
        shard = self._shard(self.epoch)
        if self.index >= len(shard):
            self.epoch, self.index = self.epoch + 1, 0
            shard = self._shard(self.epoch)
        room = int(shard[self.index])
        self.index += 1
        return room

    def state_dict(self) -> dict:
        return {"epoch": self.epoch, "index": self.index}

    def load_state_dict(self, state: dict) -> None:
        self.epoch, self.index = int(state["epoch"]), int(state["index"])


class CropDataset:
    """Rooms (loaded lazily, kept in memory) + crop settings -> batches."""

    def __init__(self, rooms: Sequence[Path | RoomData], settings: CropSettings, image_size: tuple[int, int] = (160, 120)):
        self.sources = list(rooms)
        self.settings = settings
        self.image_size = tuple(image_size)
        self._cache: dict[int, RoomData] = {}

    def __len__(self) -> int:
        return len(self.sources)

    def room(self, i: int) -> RoomData:
        if i not in self._cache:
            src = self.sources[i]
            self._cache[i] = src if isinstance(src, RoomData) else load_room(src, self.image_size, self.settings.stereo)
        return self._cache[i]

    def batch(self, room_ids: Sequence[int], rng: np.random.Generator) -> TrainBatch:
        samples = [make_crop(self.room(i), self.settings, rng) for i in room_ids]
        return collate(samples, self.settings.crop_size)
