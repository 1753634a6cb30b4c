"""Where a result's JSON sidecar goes: beside the file, with its suffix replaced (`room.glb` ->
`room.json`). Below the commands that write one (`engine reconstruct`, `engine texture`), so neither
imports the other for it."""

from __future__ import annotations

from pathlib import Path


def sidecar_path(result_path: Path) -> Path:
    """The sidecar of a mesh or textured file: the same path with the suffix .json."""
    return Path(result_path).with_suffix(".json")
