"""The built extension zip installs and enables in a clean Blender, as a user would get it.

The other tests mount the checkout; this one catches a zip that misses files (a too-broad build
exclude) or an add-on that only works from the source tree. It runs in a subprocess with its own
BLENDER_USER_RESOURCES, because installing into this test process would register a second `vortx`.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from conftest import REPO

INSTALL_AND_USE = textwrap.dedent(
    """
    import sys
    import bpy

    result = bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo="user_default", enable_on_install=True)
    assert result == {"FINISHED"}, result
    assert "bl_ext.user_default.vortx" in bpy.context.preferences.addons
    scene = bpy.context.scene
    assert abs(scene.vortx.voxel_size - 0.04) < 1e-6
    assert bpy.ops.vortx.import_capture.poll()
    # Installed add-ons are also imported as a package: the engine must come along in the zip.
    from bl_ext.user_default.vortx.engine.capture import load_capture  # noqa: F401
    print("INSTALLED-OK")
    """
)


@pytest.mark.slow
def test_built_zip_installs_and_enables(tmp_path: Path) -> None:
    import bpy

    blender_ext = Path(bpy.__file__).resolve().parents[2] / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    dist = tmp_path / "dist"
    dist.mkdir()
    build = subprocess.run(
        [sys.executable, str(blender_ext), "build", "--source-dir", str(REPO), "--output-dir", str(dist)],
        capture_output=True, text=True, timeout=120,
    )
    assert build.returncode == 0, build.stdout + build.stderr
    (archive,) = dist.glob("vortx-*.zip")

    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    install = subprocess.run(
        [sys.executable, "-c", INSTALL_AND_USE, str(archive)], capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path,
    )
    assert "INSTALLED-OK" in install.stdout, install.stdout[-3000:] + install.stderr[-3000:]
