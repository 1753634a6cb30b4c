"""Shared test fixtures.

Blender is used as the `bpy` module. `BLENDER_USER_RESOURCES` must point at a private folder
*before* bpy is imported, so tests never touch a real user's preferences. The `blender` fixture
mounts this checkout as a local extension repository and enables it exactly as an installed
extension runs (module `bl_ext.dev.vortx`).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest

from engine.process_guards import keep_triton_out

# Tests render with Workbench and then train in the same process (see engine/process_guards.py).
keep_triton_out()

REPO = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO.parent / "shared" / "data"
EXTENSION_MODULE = "bl_ext.dev.vortx"

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="vortx-blender-user-"))

sys.path.insert(0, str(REPO / "scripts"))
from _extension_dev import mount_checkout  # noqa: E402  (scripts/ is not a package)


def shared_dataset(name: str) -> Path:
    """Path to ../shared/data/<name>, or skip the test with a clear reason when it is absent."""
    path = SHARED_DATA / name
    if not path.is_dir():
        pytest.skip(f"real test data not available: {path} is missing (only present beside the team's checkout)")
    return path


@pytest.fixture(scope="session")
def blender():
    """The bpy module with this checkout enabled as the `vortx` extension. Returns the add-on module."""
    import bpy  # noqa: F401  (imported after BLENDER_USER_RESOURCES is set above)

    # One implementation with the batch script: scripts/_extension_dev.py.
    mount_checkout(Path(os.environ["BLENDER_USER_RESOURCES"]) / "dev-extensions", repo_module="dev", checkout=REPO)
    module = sys.modules.get(EXTENSION_MODULE)
    assert module is not None, f"{EXTENSION_MODULE} did not load"
    return module


@pytest.fixture
def empty_scene(blender):
    """A fresh empty scene per test (keeps the extension enabled; read_factory_settings would not)."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene


# --- helpers for the Blender-side tests (tests/vortx_blender, tests/operators, tests/ui) ----------


def look_at_pose(eye, target, up=(0.0, 0.0, 1.0)):
    """Camera-to-world (4, 4) float64 in OpenCV axes (x right, y down, z forward) looking at `target`."""
    from engine.geometry.cameras import look_at

    return look_at(eye, target, up)


def scene_state(scene) -> dict:
    """Everything an import could change, as plain values: objects, collections, cameras, settings, render."""
    import bpy

    objects = {
        obj.name: (obj.type, tuple(round(v, 6) for row in obj.matrix_world for v in row), tuple(sorted(c.name for c in obj.users_collection)))
        for obj in bpy.data.objects
    }
    settings = scene.vortx
    values = {
        p.identifier: getattr(settings, p.identifier) for p in settings.bl_rna.properties if p.identifier != "rna_type"
    }
    render = scene.render
    return {
        "objects": objects,
        "collections": sorted(c.name for c in bpy.data.collections),
        "scene_collections": sorted(c.name for c in scene.collection.children_recursive),
        "cameras": sorted(c.name for c in bpy.data.cameras),
        "settings": values,
        "render": (render.resolution_x, render.resolution_y, render.pixel_aspect_x, render.pixel_aspect_y),
        "scene_camera": scene.camera.name if scene.camera else None,
    }


@pytest.fixture(scope="module")
def single_torch_thread():
    """One intra-op torch thread for a module of tiny tensors: on a busy 2-core machine two spinning
    OpenMP threads make them 30-100x slower. Use with `pytest.mark.usefixtures`."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
