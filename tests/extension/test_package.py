"""`make extension`: the zip Blender's builder makes from this checkout, installed into a clean Blender,
runs the whole job from the installed copy (bl_ext.user_default.vortx): Import Capture, Estimate
Poses (real structure from motion on a ray-cast room), Reconstruct (seeded random weights).

Installing runs in a subprocess with its own BLENDER_USER_RESOURCES: one bpy process cannot be
reset, and this test process already has the checkout mounted as bl_ext.dev.vortx.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import ExifTags, Image

from build_extension import build
from conftest import REPO, look_at_pose

INSTALLED = "bl_ext.user_default.vortx"

INSTALL_AND_RUN = textwrap.dedent(
    """
    import json, os, sys
    import bpy

    archive, photos = sys.argv[1], sys.argv[2]
    assert bpy.ops.extensions.package_install_files(filepath=archive, repo="user_default", enable_on_install=True) == {"FINISHED"}
    addon = sys.modules["bl_ext.user_default.vortx"]
    user = os.path.realpath(os.environ["BLENDER_USER_RESOURCES"])
    sources = {name: os.path.realpath(module.__file__) for name, module in
               (("addon", addon), ("engine", addon.engine), ("dependencies", addon.vortx_blender.dependencies))}
    deps = addon.vortx_blender.dependencies
    missing = [s.requirement.distribution for s in deps.status(refresh=True) if s.needs_install]
    folder = str(addon.vortx_blender.preferences.install_folder())

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    settings = scene.vortx
    assert bpy.ops.vortx.import_capture(filepath=photos) == {"FINISHED"}
    before = settings.posed_frame_count
    assert bpy.ops.vortx.estimate_poses() == {"FINISHED"}
    posed = settings.posed_frame_count
    settings.weights_source = "RANDOM"
    settings.method = "VORTX"
    settings.voxel_size, settings.tile_size, settings.view_count = 0.16, 8, 3
    settings.image_size, settings.colour_views, settings.max_room_size = 160, 3, (2.0, 2.0, 2.0)
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    results = addon.vortx_blender.result.result_objects(scene)
    print("PACKAGE " + json.dumps({
        "user": user, "sources": sources, "missing": missing, "folder": folder, "on_path": folder in sys.path,
        "posed_before": before, "posed": posed, "frames": settings.frame_count,
        "results": [(o.name, len(o.data.polygons)) for o in results],
    }))
    """
)


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    return build(REPO, tmp_path_factory.mktemp("dist"))


def test_zip_holds_the_extension_and_not_the_dev_files(archive: Path) -> None:
    names = zipfile.ZipFile(archive).namelist()
    tops = {name.split("/")[0] for name in names}
    for required in ("blender_manifest.toml", "__init__.py", "engine/recon/driver.py", "engine/poses/sfm.py",
                     "vortx_blender/dependencies.py", "vortx_blender/preferences.py", "operators/__init__.py",
                     "requirements.txt", "constraints.txt"):  # the package installer reads its pins from the last two
        assert required in names, required
    assert not tops & {"tests", "scripts", "devtools", "samples", "docs", "data", "runs", "configs", "out", "dist", ".venv", ".git", "Makefile"}, tops
    assert not any(n.endswith(".pyc") or "__pycache__" in n for n in names)
    shipped_weights = sorted(p.relative_to(REPO).as_posix() for p in (REPO / "weights").glob("*") if p.is_file() and not p.name.startswith("."))
    assert all(w in names for w in shipped_weights), shipped_weights


def test_build_rules_ship_weights_and_drop_samples(tmp_path: Path) -> None:
    # The default weights may not be in the checkout yet: the manifest's rules are checked on a
    # stand-in source tree with a weights file, a sample capture and dev folders.
    source = tmp_path / "src"
    source.mkdir()
    shutil.copy(REPO / "blender_manifest.toml", source)
    files = ["__init__.py", "weights/vortx-default.safetensors", "weights/vortx-default.json", "samples/demo_room/images/0.jpg",
             "scripts/demo.py", "devtools/demo/pipeline.py", "tests/test_x.py", "engine/__init__.py", "requirements.txt", "docs/a.md"]
    for name in files:
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        (source / name).write_text("def register():\n    pass\n\n\ndef unregister():\n    pass\n" if name == "__init__.py" else "x")
    names = set(zipfile.ZipFile(build(source, tmp_path / "dist")).namelist())
    assert {"weights/vortx-default.safetensors", "weights/vortx-default.json", "engine/__init__.py", "requirements.txt"} <= names
    assert not {n for n in names if n.split("/")[0] in ("samples", "scripts", "devtools", "tests", "docs")}, names


# --- the installed copy runs the whole job ---------------------------------------------------------


def _photos_of_a_room(folder: Path) -> None:
    """Ten JPEGs (320x240, EXIF 35 mm focal) of a ray-cast textured box room, cameras on a circle
    looking across it: what tests/vortx_blender/test_capture_real.py shows SfM registers reliably."""
    from fixtures_raycast_room import render_room, wall_textures

    room, size, f35 = np.array([4.0, 4.0, 2.5]), (320, 240), 30
    f = f35 * np.hypot(*size) / np.hypot(36.0, 24.0)
    K = np.array([[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1]])
    walls = wall_textures(seed=0)
    folder.mkdir(parents=True)
    for i, a in enumerate(np.linspace(0, 2 * np.pi, 10, endpoint=False)):
        eye = np.array([2.0 + 1.2 * np.cos(a), 2.0 + 1.2 * np.sin(a), 1.5])
        pose = look_at_pose(eye, [2.0 - 1.5 * np.cos(a - 0.5), 2.0 - 1.5 * np.sin(a - 0.5), 1.3])
        exif = Image.Exif()
        exif.get_ifd(ExifTags.IFD.Exif)[0xA405] = f35  # FocalLengthIn35mmFilm
        Image.fromarray(render_room(K, pose, size, room, walls)).save(folder / f"{i:03d}.jpg", exif=exif, quality=95)


@pytest.mark.slow
def test_installed_zip_imports_estimates_and_reconstructs(archive: Path, tmp_path: Path) -> None:
    photos = tmp_path / "photos"
    _photos_of_a_room(photos)
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    run = subprocess.run([sys.executable, "-c", INSTALL_AND_RUN, str(archive), str(photos)],
                         capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    line = next((l for l in run.stdout.splitlines() if l.startswith("PACKAGE ")), None)
    assert run.returncode == 0 and line is not None, run.stdout[-4000:] + run.stderr[-4000:]
    result = json.loads(line[len("PACKAGE "):])

    # Everything ran from the installed copy, not from this checkout.
    installed = Path(result["user"]) / "extensions" / "user_default" / "vortx"
    for name, source in result["sources"].items():
        assert Path(source).is_relative_to(installed), (name, source)
    # Its preferences find the pins in the zip and the packages of this venv; its install folder is on sys.path.
    assert result["missing"] == []
    assert Path(result["folder"]) == Path(result["user"]) / "extensions" / ".user" / "user_default" / "vortx" / "site-packages"
    assert result["on_path"]

    assert result["frames"] == 10 and result["posed_before"] == 0 and result["posed"] >= 8
    (mesh,) = result["results"]
    assert mesh[1] > 0
