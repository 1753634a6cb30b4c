"""Reconstruction: keyframes, bounds, tiles, view selection, the inference driver, mesh and colours.

`reconstruct(capture, settings, progress=None, cancel=None) -> ReconResult` is the entry point.
Planning (`plan_reconstruction`, `tile_grid`, `Tile`) is numpy-only, so the Blender tile overlay can
import it without torch; `reconstruct` and the driver are imported on first use.
"""

from __future__ import annotations

from typing import Any

from .plan import ReconPlan, plan_reconstruction
from .recon_result import ReconResult
from .settings import ReconSettings
from .tiles import BOX_EDGES, Tile, TileState, VoxelGrid, tile_grid

__all__ = [
    "BOX_EDGES",
    "ReconPlan",
    "ReconResult",
    "ReconSettings",
    "Tile",
    "TileState",
    "VoxelGrid",
    "plan_reconstruction",
    "reconstruct",
    "tile_grid",
]


def __getattr__(name: str) -> Any:
    if name == "reconstruct":
        from .driver import reconstruct  # defers torch (the driver imports it) until someone asks for it

        return reconstruct
    raise AttributeError(name)
