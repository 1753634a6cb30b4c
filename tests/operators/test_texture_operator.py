"""vortx.bake_texture as the sidebar button runs it: modal, progress in the status bar, Esc cancels and
changes nothing; which result it bakes (the active one, else the newest); greyed out without one.

Headless Blender has no events, so the operator's own methods run on a stand-in that Blender would
hold as a modal operator (as tests/vortx_blender/test_reconstruct.py does for Reconstruct).
"""

from __future__ import annotations

import importlib
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fixtures_modal import WindowManager, Workspace, modal_operator, tick_until_done
from fixtures_texture import make_box_capture, room_mesh, textured_scene


@pytest.fixture(scope="module")
def capture_dir(blender, tmp_path_factory) -> Path:
    return make_box_capture(blender, tmp_path_factory.mktemp("bake_operator") / "box_room")


BAKE_METHODS = ("job_title", "make_job_function", "apply_result")


def _state(scene) -> dict:
    import bpy

    return {"meshes": sorted((m.name, len(m.vertices), len(m.uv_layers)) for m in bpy.data.meshes),
            "materials": sorted(m.name for m in bpy.data.materials), "images": sorted(i.name for i in bpy.data.images)}


def test_modal_bake_shows_progress_and_esc_cancels(blender, capture_dir, monkeypatch) -> None:
    import bpy

    vr = importlib.import_module(f"{blender.__name__}.engine.texture.vr")
    real = vr.textured_result
    baking, finish = threading.Event(), threading.Event()

    def held(mesh, views, options, progress=None, cancel=None):
        progress("texture: bake", 2, 6)
        baking.set()
        while not finish.is_set():
            cancel.check()  # Esc lands here
            time.sleep(0.005)
        return real(mesh, views, options, progress, cancel)

    monkeypatch.setattr(vr, "textured_result", held)
    scene, obj = textured_scene(blender, capture_dir)
    context = SimpleNamespace(scene=scene, active_object=None, window=object(), window_manager=WindowManager(),
                              workspace=Workspace(), screen=None, evaluated_depsgraph_get=bpy.context.evaluated_depsgraph_get)
    before = _state(scene)

    op = modal_operator(blender, "VORTX_OT_bake_texture", BAKE_METHODS)
    assert op.execute(context) == {"RUNNING_MODAL"}
    assert baking.wait(10)
    time.sleep(0.05)
    assert op.modal(context, SimpleNamespace(type="TIMER", value="NOTHING")) == {"RUNNING_MODAL"}
    assert context.workspace.status[-1].startswith("VoRTX Bake Texture: texture: bake 2/6")
    assert op.modal(context, SimpleNamespace(type="ESC", value="PRESS")) == {"RUNNING_MODAL"}
    assert tick_until_done(op, context, 20.0) == {"CANCELLED"}
    assert ({"WARNING"}, "Bake Texture cancelled; nothing was changed") in op.reports
    assert _state(scene) == before and not blender.vortx_blender.jobs.is_busy()

    finish.set()  # the next run goes through to the end
    op = modal_operator(blender, "VORTX_OT_bake_texture", BAKE_METHODS)
    assert op.execute(context) == {"RUNNING_MODAL"}
    assert tick_until_done(op, context, 20.0) == {"FINISHED"}
    assert blender.vortx_blender.result.is_textured(obj)
    assert context.workspace.status[-1] is None and context.window_manager.timers == set()
    (info,) = [message for kind, message in op.reports if kind == {"INFO"}]
    assert info.startswith("Baked a 512 x 512 texture onto 'box_room':") and "from 6 photos" in info


def test_bakes_the_active_result_else_the_newest(blender, capture_dir) -> None:
    import bpy

    results = blender.vortx_blender.result
    scene, first = textured_scene(blender, capture_dir)
    provenance = results.Provenance(str(capture_dir), {}, "stereo", {})
    second = results.insert_result(scene, room_mesh(blender), provenance, mode="ADD")
    assert (first.name, second.name) == ("box_room", "box_room.001")
    bpy.context.view_layer.objects.active = None
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    assert results.is_textured(second) and not results.is_textured(first)
    bpy.context.view_layer.objects.active = first
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    assert results.is_textured(first)
    names = {results.texture_image_of(o.active_material).name for o in (first, second)}
    assert names == {"box_room Texture", "box_room.001 Texture"}


def test_greyed_out_without_a_result_or_while_a_job_runs(blender, empty_scene) -> None:
    import bpy

    assert not bpy.ops.vortx.bake_texture.poll()
    results = blender.vortx_blender.result
    mesh = blender.engine.mesh_io.Mesh(vertices=np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), faces=np.int32([[0, 1, 2]]))
    results.insert_result(empty_scene, mesh, results.Provenance("/captures/hall", {}, "stereo", {}))
    assert bpy.ops.vortx.bake_texture.poll()
    release = threading.Event()
    job = blender.vortx_blender.jobs.Job("Reconstruct", lambda progress, cancel: release.wait(10)).start()
    try:
        assert not bpy.ops.vortx.bake_texture.poll()
    finally:
        release.set()
        job.wait()
