"""The extension registers in a Blender whose Python lacks the engine's packages, and its preferences
say which are missing (users reach the Install button only if registering does not need them).

Each case runs in a subprocess with its own BLENDER_USER_RESOURCES, where an import hook makes the
named top-level modules unimportable, as in a stock Blender.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from conftest import REPO

LOAD_WITHOUT = textwrap.dedent(
    """
    import json, sys
    BLOCKED = set(sys.argv[1].split(","))

    class Absent:
        # A meta-path finder that fails first: the module is absent whatever else is installed.
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None

    sys.meta_path.insert(0, Absent())
    sys.path.insert(0, sys.argv[2])
    import bpy
    from _extension_dev import mount_checkout, ExtensionLoadError

    try:
        module_name = mount_checkout(sys.argv[3], repo_module="dev")
    except ExtensionLoadError as error:
        print("RESULT " + json.dumps({"loaded": False, "error": str(error)}))
        sys.exit(0)
    module = sys.modules[module_name]
    statuses = module.vortx_blender.dependencies.status(refresh=True)
    print("RESULT " + json.dumps({
        "loaded": True,
        "operators": [hasattr(bpy.types, n) for n in ("VORTX_OT_import_capture", "VORTX_OT_install_dependencies")],
        "missing": sorted(s.requirement.module for s in statuses if s.missing),
        "imported": sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED),
    }))
    """
)


def _load_without(modules: list[str], tmp_path: Path) -> dict:
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    run = subprocess.run(
        [sys.executable, "-c", LOAD_WITHOUT, ",".join(modules), str(REPO / "scripts"), str(tmp_path / "repo")],
        capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path,
    )
    lines = [l for l in run.stdout.splitlines() if l.startswith("RESULT ")]
    assert run.returncode == 0 and lines, run.stdout[-3000:] + run.stderr[-3000:]
    return json.loads(lines[-1][len("RESULT "):])


def test_registers_without_torch_pycolmap_skimage_safetensors_scipy(tmp_path: Path) -> None:
    blocked = ["torch", "pycolmap", "skimage", "safetensors", "scipy"]
    result = _load_without(blocked, tmp_path)
    assert result["loaded"], result
    assert result["operators"] == [True, True]
    assert result["missing"] == sorted(blocked)  # the preferences list exactly these as missing
    assert result["imported"] == []


def test_registers_without_opencv_and_pillow(tmp_path: Path) -> None:
    result = _load_without(["cv2", "PIL"], tmp_path)
    assert result["loaded"], result
    assert result["missing"] == ["PIL", "cv2"]
