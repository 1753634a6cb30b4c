"""2D features, computed once per keyframe and cached on the CPU for every tile that uses the view.

Official inference computes each frame's feature pyramid once and keeps it as fp16 on the CPU
(vortx-spec.md section 4); tiles then gather the maps of their own views. Images go through the 2D
CNN `chunk` at a time (about 4 was fastest on CPU, platform-notes section 4) so a long capture never
needs all images in memory at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import torch

from ..capture import Frame
from ..capture.images import load_resized, resized_size
from ..jobs import CancelToken, ProgressCallback, check, report
from ..geometry.cameras import scale_intrinsics


@dataclass
class FeatureCache:
    """levels[l]: (V, C_l, H_l, W_l) on the CPU; Ks: (V, 3, 3) float32 in pixels of the resized
    images; poses: (V, 4, 4) float32 camera-to-world; image_hw: (H, W) of the resized images."""

    levels: list[torch.Tensor]
    Ks: torch.Tensor
    poses: torch.Tensor
    image_hw: tuple[int, int]

    @property
    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in self.levels)

    def views(self, level: int, ids: np.ndarray, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Features (v, C, H, W) float32, K (v, 3, 3) and poses (v, 4, 4) of keyframes `ids` on `device`."""
        index = torch.as_tensor(np.asarray(ids, dtype=np.int64))
        feats = self.levels[level].index_select(0, index).to(device=device, dtype=torch.float32)
        return feats, self.Ks[index].to(device), self.poses[index].to(device)


def keyframe_image_size(frames: Sequence[Frame], long_side: int) -> tuple[int, int]:
    """(w, h) every keyframe is resized to; loaders guarantee one resolution per capture."""
    return resized_size(frames[0].width, frames[0].height, long_side)


@torch.inference_mode()
def encode_keyframes(
    model: torch.nn.Module,
    frames: Sequence[Frame],
    Ks: np.ndarray,
    poses: np.ndarray,
    image_size: tuple[int, int],
    device: torch.device,
    chunk: int = 4,
    fp16: bool = True,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
) -> FeatureCache:
    """Run `model.encode_views` over all keyframes.

    Ks: (V, 3, 3) pixels of the images on disk; poses: (V, 4, 4); image_size: (w, h) to resize to.
    """
    w, h = image_size
    K_resized = np.stack([scale_intrinsics(K, (f.width, f.height), (w, h)) for K, f in zip(Ks, frames)])
    Ks_t = torch.as_tensor(K_resized, dtype=torch.float32)
    poses_t = torch.as_tensor(np.asarray(poses), dtype=torch.float32)
    store_dtype = torch.float16 if fp16 else torch.float32
    levels: list[torch.Tensor] = []
    total = len(frames)
    report(progress, "features", 0, total)
    for start in range(0, total, chunk):
        check(cancel)
        stop = min(start + chunk, total)
        images = np.stack([load_resized(f, (w, h)) for f in frames[start:stop]])  # (c, h, w, 3) uint8
        batch = torch.from_numpy(images).permute(0, 3, 1, 2).to(device=device, dtype=torch.float32)
        maps = model.encode_views(batch, Ks_t[start:stop].to(device), poses_t[start:stop].to(device))
        if not levels:
            # Allocate the whole cache once the per-level shapes are known: no list of chunks to concatenate.
            levels = [torch.empty((total, *m.shape[1:]), dtype=store_dtype) for m in maps]
        for cache, m in zip(levels, maps):
            cache[start:stop] = m.to(device="cpu", dtype=store_dtype)
        report(progress, "features", stop, total)
    return FeatureCache(levels, Ks_t, poses_t, (h, w))
