"""Plane-sweep multi-view stereo: a depth and a confidence per keyframe pixel, no learning.

The depths are the domain-independent geometric evidence of the reconstruction
(../shared/design/stereo-evidence.md): fused into a TSDF they are the classical `stereo` method, and
they are the extra input of VoRTX with geometric evidence.
"""

from __future__ import annotations

import importlib
from typing import Any

# Names are imported on first use: `engine.recon.settings` reads `stereo.options` (numpy only), and
# planning and the extension's registration must not pay for (or need) torch, which depth_maps imports.
_HOMES = {
    "DepthMap": ".depth_maps",
    "estimate_depth_maps": ".depth_maps",
    "stereo_references": ".depth_maps",
    "fuse_depth_maps": ".fused_tsdf",
    "StereoOptions": ".options",
    "select_sources": ".source_views",
    "sweep_depth": ".sweep",
}

__all__ = ["DepthMap", "StereoOptions", "fuse_depth_maps", "estimate_depth_maps", "select_sources", "stereo_references", "sweep_depth"]


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_HOMES[name], __name__), name)
