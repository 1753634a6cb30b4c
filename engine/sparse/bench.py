"""Timing of the sparse submanifold convolution against a dense Conv3d on the same volume.

Used by ``python -m engine bench``. Two kinds of active sets:
- surface-like (``occupancy=None``): a one-voxel-thick room shell (floor, ceiling, four walls) plus
  box-shaped furniture surfaces, which is what pruned VoRTX levels look like (about 9 active
  neighbours per voxel in a 3^3 kernel);
- random (``occupancy=f``): each voxel active with probability f.
"""

from __future__ import annotations

import time
from typing import Callable

import torch
import torch.nn.functional as F
from torch import Tensor

from .conv import conv3d, submanifold_map
from .tensor import SparseVoxels


def surface_coords(grid: tuple[int, int, int], num_boxes: int = 6, seed: int = 0) -> Tensor:
    """(N, 3) int64 voxels of a room shell filling ``grid`` plus ``num_boxes`` box surfaces inside it."""
    gen = torch.Generator().manual_seed(seed)
    occupied = torch.zeros(grid, dtype=torch.bool)
    _box_surface(occupied, (0, 0, 0), tuple(g - 1 for g in grid))
    for _ in range(num_boxes):
        size = [int(torch.randint(max(2, g // 10), max(3, g // 4), (1,), generator=gen)) for g in grid]
        lo = [int(torch.randint(1, max(2, g - s - 1), (1,), generator=gen)) for g, s in zip(grid, size)]
        hi = [min(l + s, g - 2) for l, s, g in zip(lo, size, grid)]
        lo[2] = 1  # furniture stands on the floor
        _box_surface(occupied, tuple(lo), tuple(hi))
    return occupied.nonzero()


def _box_surface(occupied: Tensor, lo: tuple[int, ...], hi: tuple[int, ...]) -> None:
    """Mark the six faces of the box [lo, hi] (inclusive) in the (X, Y, Z) boolean grid."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    occupied[x0 : x1 + 1, y0 : y1 + 1, z0] = True
    occupied[x0 : x1 + 1, y0 : y1 + 1, z1] = True
    occupied[x0 : x1 + 1, y0, z0 : z1 + 1] = True
    occupied[x0 : x1 + 1, y1, z0 : z1 + 1] = True
    occupied[x0, y0 : y1 + 1, z0 : z1 + 1] = True
    occupied[x1, y0 : y1 + 1, z0 : z1 + 1] = True


def _best_time(fn: Callable[[], None], repeats: int, device: torch.device) -> float:
    """Best wall time of ``repeats`` calls after one warm-up call (seconds)."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        start = time.perf_counter()
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        best = min(best, time.perf_counter() - start)
    return best


def bench_sparse_vs_dense(
    grid: tuple[int, int, int] = (96, 96, 48),
    channels: int = 32,
    occupancy: float | None = None,
    repeats: int = 3,
    dense: bool = True,
    device: str | torch.device | None = None,
    seed: int = 0,
) -> dict[str, object]:
    """Time a 3^3 submanifold conv (channels -> channels) against ``Conv3d`` on the full grid.

    occupancy: None for a surface-like active set, else the fraction of active voxels (random).
    dense: also time the dense Conv3d (set False for grids too large to hold densely).
    Returns voxel/pair counts and best-of-``repeats`` seconds: ``kernel_map_s`` (map build, once
    per scene and level in practice), ``sparse_forward_s`` / ``dense_forward_s`` (no grad) and
    ``sparse_forward_backward_s`` / ``dense_forward_backward_s`` (grads for features and weights).
    """
    dev = torch.device(device) if device is not None else torch.device("cuda" if torch.cuda.is_available() else "cpu")
    gen = torch.Generator().manual_seed(seed)
    if occupancy is None:
        xyz = surface_coords(grid, seed=seed)
    else:
        xyz = (torch.rand(grid, generator=gen) < occupancy).nonzero()
    coords = torch.cat([torch.zeros(len(xyz), 1, dtype=torch.int64), xyz], dim=1).to(dev)
    feats = torch.randn(len(coords), channels, generator=gen).to(dev)
    kernel = (torch.randn(27, channels, channels, generator=gen) / (27 * channels) ** 0.5).to(dev)

    def build_map() -> None:
        submanifold_map(SparseVoxels(coords, feats), 3)

    x = SparseVoxels(coords, feats)
    kmap = submanifold_map(x, 3)

    def sparse_forward() -> None:
        with torch.no_grad():
            conv3d(x, kernel, 3)

    def sparse_forward_backward() -> None:
        f = feats.detach().requires_grad_()
        w = kernel.detach().requires_grad_()
        conv3d(x.replace_feats(f), w, 3).feats.sum().backward()

    result: dict[str, object] = {
        "device": str(dev),
        "grid": tuple(grid),
        "channels": channels,
        "pattern": "surface" if occupancy is None else f"random {occupancy:g}",
        "voxels": len(coords),
        "pairs": kmap.num_pairs(),
        "neighbours_per_voxel": kmap.num_pairs() / max(1, len(coords)),
        "kernel_map_s": _best_time(build_map, repeats, dev),
        "sparse_forward_s": _best_time(sparse_forward, repeats, dev),
        "sparse_forward_backward_s": _best_time(sparse_forward_backward, repeats, dev),
    }
    if dense:
        volume = torch.zeros(1, channels, *grid, device=dev)
        volume[0, :, xyz[:, 0], xyz[:, 1], xyz[:, 2]] = feats.t()
        weight = kernel.view(3, 3, 3, channels, channels).permute(4, 3, 2, 1, 0).contiguous()

        def dense_forward() -> None:
            with torch.no_grad():
                F.conv3d(volume, weight, padding=1)

        def dense_forward_backward() -> None:
            v = volume.detach().requires_grad_()
            w = weight.detach().requires_grad_()
            F.conv3d(v, w, padding=1).sum().backward()

        result["dense_forward_s"] = _best_time(dense_forward, repeats, dev)
        result["dense_forward_backward_s"] = _best_time(dense_forward_backward, repeats, dev)
        result["speedup_forward"] = result["dense_forward_s"] / result["sparse_forward_s"]  # type: ignore[operator]
        result["speedup_forward_backward"] = (
            result["dense_forward_backward_s"] / result["sparse_forward_backward_s"]  # type: ignore[operator]
        )
    return result
