"""A fused TSDF volume and its file format (`.npz`: tsdf, weight, origin, voxel_size, trunc)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Union

import numpy as np

from ..errors import VortxError
from .grid import voxel_positions


@dataclass
class TsdfVolume:
    """tsdf (X, Y, Z) float32 in the ground-truth convention (-1 observed free, +1 unobserved);
    weight (X, Y, Z) float32 (frames that updated a voxel; > 0 = observed); origin (3,) float64 is
    the world position of voxel (0, 0, 0) (corner convention); voxel_size and trunc in metres."""

    tsdf: np.ndarray
    weight: np.ndarray
    origin: np.ndarray
    voxel_size: float
    trunc: float

    @property
    def dims(self) -> tuple[int, int, int]:
        return tuple(int(d) for d in self.tsdf.shape)  # type: ignore[return-value]

    @property
    def observed(self) -> np.ndarray:
        """(X, Y, Z) bool: voxels at least one frame updated."""
        return self.weight > 0

    def positions(self) -> np.ndarray:
        """(X, Y, Z, 3) float32 world positions of the voxel samples."""
        return voxel_positions(self.origin, self.dims, self.voxel_size).numpy()

    def save(self, path: Union[str, Path]) -> None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        # float16 would lose the exact +-1 the convention relies on only for |x| near 1: keep float32,
        # the +-1 runs compress well.
        np.savez_compressed(path, tsdf=self.tsdf.astype(np.float32), weight=self.weight.astype(np.float32),
                            origin=np.asarray(self.origin, np.float64), voxel_size=np.float64(self.voxel_size),
                            trunc=np.float64(self.trunc))

    @classmethod
    def load(cls, path: Union[str, Path]) -> "TsdfVolume":
        path = Path(path)
        try:
            with np.load(path) as z:
                return cls(z["tsdf"], z["weight"], z["origin"], float(z["voxel_size"]), float(z["trunc"]))
        except (OSError, KeyError, ValueError) as error:
            raise VortxError(f"{path}: not a TSDF volume file ({error}); write one with "
                             "`python -m engine synth` or TsdfVolume.save") from error
