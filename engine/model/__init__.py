"""The VoRTX network (3DV 2021) in pure PyTorch: 2D pyramid -> back-projection -> transformer view
fusion with projective occupancy -> coarse-to-fine sparse 3D CNN -> TSDF.

Public API (see docs/developers.md, "Model"):
    VortxConfig, VortxNet, VortxBatch, FusionOutput, LevelOutput, LevelPrediction,
    save_weights, load_weights, read_config, tsdf_from_logits, LEVEL_NAMES.
"""

from .config import LEVEL_NAMES, VortxConfig
from .outputs import FusionOutput, LevelOutput, LevelPrediction, VortxBatch, tsdf_from_logits
from .vortx import VortxNet
from .weights import load_weights, read_config, save_weights

__all__ = [
    "LEVEL_NAMES",
    "FusionOutput",
    "LevelOutput",
    "LevelPrediction",
    "VortxBatch",
    "VortxConfig",
    "VortxNet",
    "load_weights",
    "read_config",
    "save_weights",
    "tsdf_from_logits",
]
