"""What a reconstruction returns: the mesh, the tiles and the numbers that explain the run."""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator, Optional

import numpy as np

from ..mesh_io import Mesh
from .tiles import Tile


def empty_mesh() -> Mesh:
    return Mesh(
        vertices=np.zeros((0, 3), np.float32),
        faces=np.zeros((0, 3), np.int32),
        normals=np.zeros((0, 3), np.float32),
        colors=np.zeros((0, 3), np.float32),
    )


@dataclass
class ReconResult:
    """mesh: vertices (V, 3) float32 world metres, faces (F, 3) int32, normals (V, 3) float32 pointing
    toward free space (the cameras), colors (V, 3) float32 0..1.
    tiles: the tile grid with each tile's final state, views and voxel counts.
    stats: JSON-serialisable timings per stage, voxels per level, views per tile, memory, settings.
    message: None on success; otherwise why the mesh is empty, in words for the user.
    """

    mesh: Mesh
    tiles: list[Tile]
    stats: dict[str, Any] = field(default_factory=dict)
    message: Optional[str] = None
    warnings: list[str] = field(default_factory=list)
    # Marching cubes' mesh before the finishing, when the finishing ran: what Finish Off gives from the
    # same run, so evaluations score both without reconstructing twice (no colours).
    unfinished_mesh: Optional[Mesh] = None

    @property
    def is_empty(self) -> bool:
        return len(self.mesh.faces) == 0


class StageTimer:
    """Wall-clock and process-CPU seconds per named stage (stages may repeat; times add up).

    CPU time is recorded too because wall time on a shared machine mostly measures the neighbours.
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.cpu_seconds: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start, cpu_start = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
            self.cpu_seconds[name] = self.cpu_seconds.get(name, 0.0) + time.process_time() - cpu_start
