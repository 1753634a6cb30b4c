"""Bake Texture in Blender (vortx_blender/texture.py through vortx.bake_texture, headless and blocking):
a VoRTX result gets the engine's textured mesh, a UV map, a packed image and a texture material;
Show Observation still switches colours; a cancelled or failing bake leaves the scene as it was.
The scene is tests/fixtures_texture.py's box room with a hand-made result mesh.
"""

from __future__ import annotations

import importlib
import json
import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from engine.observation import OBSERVATIONS
from fixtures_texture import image_rows_top_first, make_box_capture, textured_scene


@pytest.fixture(scope="module")
def capture_dir(blender, tmp_path_factory) -> Path:
    return make_box_capture(blender, tmp_path_factory.mktemp("texture") / "box_room")


@pytest.fixture
def engine_spy(blender, monkeypatch):
    """Records what engine.texture.vr.textured_result got and returned (the job imports it per run)."""
    vr = importlib.import_module(f"{blender.__name__}.engine.texture.vr")
    real = vr.textured_result
    calls: list[SimpleNamespace] = []

    def spy(mesh, views, options, progress=None, cancel=None):
        call = SimpleNamespace(mesh=mesh, views=list(views), options=options)
        calls.append(call)
        call.textured, call.stats = real(mesh, views, options, progress, cancel)
        return call.textured, call.stats

    monkeypatch.setattr(vr, "textured_result", spy)
    return calls


def data_state(scene) -> dict:
    """The datablocks a bake could change, as plain values."""
    import bpy

    return {
        "meshes": sorted((m.name, len(m.vertices), len(m.polygons), len(m.uv_layers), m.users) for m in bpy.data.meshes),
        "materials": sorted((m.name, m.users) for m in bpy.data.materials),
        "images": sorted(i.name for i in bpy.data.images),
        "objects": sorted((o.name, o.data.name if o.data else None, len(o.modifiers), o.get("vortx_texture"))
                          for o in scene.objects),
    }


def positions(mesh) -> np.ndarray:
    values = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.attributes["position"].data.foreach_get("vector", values)
    return values.reshape(-1, 3)


def base_colour_source(material) -> str:
    principled = next(node for node in material.node_tree.nodes if node.type == "BSDF_PRINCIPLED")
    (link,) = principled.inputs["Base Color"].links
    return link.from_node.name


def test_bake_gives_the_result_the_engines_texture(blender, capture_dir, engine_spy) -> None:
    import bpy

    results = blender.vortx_blender.result
    scene, obj = textured_scene(blender, capture_dir)
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    (call,) = engine_spy
    textured = call.textured
    assert call.options.texture_size == 512 and call.options.face_budget == 200
    assert call.options.occlusion_tolerance == pytest.approx(2 * scene.vortx.voxel_size)
    assert len(call.views) == 6 and len(call.mesh.faces) == 6 * 2 * 36

    obj = bpy.data.objects["box_room"]
    mesh = obj.data
    assert mesh.name == "box_room" and len(bpy.data.meshes) == 1  # the untextured mesh went
    np.testing.assert_array_equal(positions(mesh), textured.vertices)  # identity transform: world metres
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.attributes[".corner_vert"].data.foreach_get("value", corners)
    np.testing.assert_array_equal(corners.reshape(-1, 3), textured.faces)
    assert len(mesh.polygons) <= 200

    # The UV map: one UV per corner, the engine's per-vertex UVs (v up, as Blender's).
    assert [layer.name for layer in mesh.uv_layers] == ["UVMap"]
    uvs = np.empty(2 * len(mesh.loops), np.float32)
    mesh.uv_layers["UVMap"].data.foreach_get("uv", uvs)
    np.testing.assert_allclose(uvs.reshape(-1, 2), textured.uvs[textured.faces.reshape(-1)], atol=1e-7)

    # The material shows the packed photo texture, pixel for pixel the engine's (bottom row first in Blender).
    material = obj.active_material
    assert material.name == "VoRTX Texture" and len(mesh.materials) == 1
    image = material.node_tree.nodes[results.TEXTURE_NODE].image
    assert image.name == "box_room Texture" and tuple(image.size) == (512, 512)
    assert image.packed_file is not None and image.colorspace_settings.name == "sRGB"
    np.testing.assert_array_equal(image_rows_top_first(image), textured.texture)
    assert base_colour_source(material) == results.TEXTURE_NODE
    principled = next(node for node in material.node_tree.nodes if node.type == "BSDF_PRINCIPLED")
    assert principled.inputs["Roughness"].default_value == 1.0 and principled.inputs["Metallic"].default_value == 0.0
    assert results.is_textured(obj)

    # The vertex colours and the confidence layer follow the new vertices.
    colour = np.empty(4 * len(mesh.vertices), np.float32)
    mesh.color_attributes["Color"].data.foreach_get("color_srgb", colour)
    np.testing.assert_allclose(colour.reshape(-1, 4)[:, :3], textured.colors, atol=2e-3)
    values = np.empty(len(mesh.vertices), np.float32)
    mesh.attributes[OBSERVATIONS].data.foreach_get("value", values)
    np.testing.assert_array_equal(values, textured.attributes[OBSERVATIONS])
    assert results.has_observation(mesh)

    # How it was made, on the object.
    record = json.loads(obj["vortx_texture"])
    assert (record["texture_size"], record["face_budget"], record["photos"]) == (512, 200, 6)
    assert record["stats"]["faces"] == len(mesh.polygons) and record["stats"]["vr"]["faces_in"] == 432
    assert blender.vortx_blender.texture.bake_summary(obj) == record


def test_show_observation_switches_a_textured_result(blender, capture_dir) -> None:
    import bpy

    results = blender.vortx_blender.result
    scene, obj = textured_scene(blender, capture_dir)
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    material = obj.active_material
    obj.vortx_show_observation = True
    assert base_colour_source(material) == results.TEXTURE_OBSERVATION_NODE
    assert results.shown_colour_attribute(obj.data) == "Observation"
    assert obj.active_material == material  # the texture stays referenced (not swapped for a shared material)
    obj.vortx_show_observation = False
    assert base_colour_source(material) == results.TEXTURE_NODE
    assert results.shown_colour_attribute(obj.data) == "Color"

    # Baking while the observation is shown keeps it shown, on the new material.
    obj.vortx_show_observation = True
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    assert base_colour_source(obj.active_material) == results.TEXTURE_OBSERVATION_NODE


def test_a_result_without_the_confidence_layer_bakes_and_toggles(blender, capture_dir) -> None:
    import bpy

    results = blender.vortx_blender.result
    scene, obj = textured_scene(blender, capture_dir, evidence=False)
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    obj.vortx_show_observation = True  # nothing to show: the texture stays
    assert base_colour_source(obj.active_material) == results.TEXTURE_NODE


def test_baking_again_replaces_the_previous_texture(blender, capture_dir) -> None:
    import bpy

    scene, obj = textured_scene(blender, capture_dir)
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    scene.vortx.texture_size = 1024
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    texture_materials = [m for m in bpy.data.materials if m.get("vortx_texture_material")]
    assert [m.users for m in texture_materials] == [1]
    assert [tuple(i.size) for i in bpy.data.images] == [(1024, 1024)]
    assert len(bpy.data.meshes) == 1


def test_modifiers_and_the_object_transform_are_baked_in(blender, capture_dir, engine_spy) -> None:
    """The bake sees the result as the viewport shows it: a Decimate modifier applied, the object moved.
    The photos see the room where the cameras are, so the mesh goes there for the bake and back after."""
    import bpy

    scene, obj = textured_scene(blender, capture_dir, face_budget=0)
    modifier = obj.modifiers.new("user decimate", "DECIMATE")
    modifier.ratio = 0.5
    modifier.use_collapse_triangulate = True
    obj.location = (0.5, -0.25, 0.1)
    bpy.context.view_layer.update()
    shown = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    shown_faces, local_min = len(shown.polygons), positions(obj.data).min(0)
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    (call,) = engine_spy
    assert len(call.mesh.faces) == shown_faces < 432
    np.testing.assert_allclose(call.mesh.vertices.min(0), local_min + np.float32([0.5, -0.25, 0.1]), atol=1e-5)
    assert len(obj.modifiers) == 0  # applied: the new mesh is their result
    assert len(obj.data.polygons) == len(call.textured.faces)
    np.testing.assert_allclose(positions(obj.data), call.textured.vertices - np.float32([0.5, -0.25, 0.1]), atol=1e-5)


def test_quads_are_triangulated_for_the_bake(blender, empty_scene) -> None:
    import bpy

    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.active_object.data
    arrays = blender.vortx_blender.result.mesh_arrays(plane, triangulate=True)
    assert arrays.faces.shape == (2, 3) and set(arrays.faces.ravel()) == {0, 1, 2, 3}
    with pytest.raises(ValueError, match="not triangles"):
        blender.vortx_blender.result.mesh_arrays(plane)


def test_cancelled_bake_changes_nothing(blender, capture_dir, monkeypatch) -> None:
    """The real engine, cancelled through the job runner (what Esc does) at its first progress report."""
    import bpy

    vr = importlib.import_module(f"{blender.__name__}.engine.texture.vr")
    real = vr.textured_result
    jobs = blender.vortx_blender.jobs
    stages: list[str] = []

    def cancelling(mesh, views, options, progress=None, cancel=None):
        def first_then_cancel(stage, done, total):
            progress(stage, done, total)
            stages.append(stage)
            jobs.active_job().cancel()

        return real(mesh, views, options, first_then_cancel, cancel)

    scene, obj = textured_scene(blender, capture_dir)
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}  # a previous texture the cancelled bake must keep
    scene.vortx.texture_size = 1024
    before = data_state(scene)
    monkeypatch.setattr(vr, "textured_result", cancelling)
    assert bpy.ops.vortx.bake_texture() == {"CANCELLED"}
    assert stages and len(stages) <= 2
    assert data_state(scene) == before and not jobs.is_busy()


def test_missing_photos_are_named_and_change_nothing(blender, capture_dir, tmp_path) -> None:
    import bpy

    copy = tmp_path / "box_room"
    shutil.copytree(capture_dir, copy)
    scene, obj = textured_scene(blender, copy)
    before = data_state(scene)
    for photo in (copy / "color").glob("*.png"):
        photo.unlink()
    with pytest.raises(RuntimeError, match=r"needs the capture's photos, but 6 of 6 are missing: 0.png, 1.png, 2.png and 3 more"):
        bpy.ops.vortx.bake_texture()
    assert data_state(scene) == before


def test_a_failure_while_building_removes_what_it_made(blender, capture_dir, monkeypatch) -> None:
    import bpy

    results = blender.vortx_blender.result
    scene, obj = textured_scene(blender, capture_dir)
    before = data_state(scene)

    def broken(image, observation):
        raise blender.engine.errors.VortxError("no material today")

    monkeypatch.setattr(results, "texture_material", broken)
    with pytest.raises(RuntimeError, match="no material today"):
        bpy.ops.vortx.bake_texture()
    assert data_state(scene) == before


def test_engine_failure_changes_nothing(blender, capture_dir, monkeypatch) -> None:
    import bpy

    vr = importlib.import_module(f"{blender.__name__}.engine.texture.vr")

    def failing(mesh, views, options, progress=None, cancel=None):
        raise blender.engine.errors.VortxError("the atlas could not be made")

    scene, obj = textured_scene(blender, capture_dir)
    before = data_state(scene)
    monkeypatch.setattr(vr, "textured_result", failing)
    with pytest.raises(RuntimeError, match="the atlas could not be made"):
        bpy.ops.vortx.bake_texture()
    assert data_state(scene) == before


def test_a_crash_of_the_atlas_library_is_reported_and_changes_nothing(blender, capture_dir, monkeypatch) -> None:
    """xatlas segfaulting (forced here) ends its worker process, not Blender: the bake fails with the step
    named, the scene keeps its previous texture, and Blender goes on (a second bake works)."""
    import bpy

    import fixtures_native

    atlas = importlib.import_module(f"{blender.__name__}.engine.texture.atlas")
    scene, obj = textured_scene(blender, capture_dir)
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    scene.vortx.texture_size = 1024
    before = data_state(scene)
    monkeypatch.setattr(atlas, "xatlas_layout", fixtures_native.segfault)
    with pytest.raises(RuntimeError, match=r"texture atlas \(xatlas\) crashed on each of 2 tries: its worker process was killed by "
                                           r"SIGSEGV\. Nothing was changed\. Try again") as caught:
        bpy.ops.vortx.bake_texture()
    shutil.rmtree(re.search(r"kept in (\S+) for a bug report", str(caught.value))[1])
    assert data_state(scene) == before and not blender.vortx_blender.jobs.is_busy()
    monkeypatch.undo()
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    assert json.loads(obj["vortx_texture"])["texture_size"] == 1024


def test_no_result_or_no_cameras_or_bad_settings_are_refused(blender, capture_dir, empty_scene) -> None:
    import bpy

    with pytest.raises(RuntimeError, match="poll"):  # no result: the button is greyed out
        bpy.ops.vortx.bake_texture()
    scene, obj = textured_scene(blender, capture_dir)
    scene.vortx.texture_size = 3000
    before = data_state(scene)
    with pytest.raises(RuntimeError, match="texture size must be one of 512, 1024, 2048, 4096, 8192, got 3000"):
        bpy.ops.vortx.bake_texture()
    scene.vortx.texture_size = 512
    for camera in [o for o in scene.objects if o.type == "CAMERA"]:
        bpy.data.objects.remove(camera)
    before = data_state(scene)
    with pytest.raises(RuntimeError, match="no posed capture cameras to bake the photos from"):
        bpy.ops.vortx.bake_texture()
    assert data_state(scene) == before


def test_operator_is_registered_with_undo(blender) -> None:
    import bpy

    assert bpy.types.VORTX_OT_bake_texture.bl_options == {"REGISTER", "UNDO"}


def test_clean_up_is_refused_on_a_textured_result(blender, capture_dir) -> None:
    """Clean Up rebuilds the mesh without UVs; on a textured result it would leave the texture on
    nothing, so it is greyed out with the reason, and the mesh stays as baked."""
    import bpy

    scene, obj = textured_scene(blender, capture_dir)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.vortx.clean_result.poll()
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    faces = len(obj.data.polygons)
    assert not bpy.ops.vortx.clean_result.poll()
    with pytest.raises(RuntimeError, match="poll"):
        bpy.ops.vortx.clean_result()
    assert len(obj.data.polygons) == faces and obj.data.uv_layers.active is not None


def test_edit_mode_is_refused_before_and_after_the_bake(blender, capture_dir, monkeypatch) -> None:
    """In Edit Mode Blender keeps its own copy of the mesh, so a swap would silently not happen: the
    bake refuses to start, and a bake that finishes after the user entered Edit Mode changes nothing."""
    import bpy

    texture = blender.vortx_blender.texture
    scene, obj = textured_scene(blender, capture_dir)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        with pytest.raises(blender.engine.errors.VortxError, match="switch to Object Mode"):
            texture.request_from_scene(scene, obj, bpy.context.evaluated_depsgraph_get())
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
    request = texture.request_from_scene(scene, obj, bpy.context.evaluated_depsgraph_get())
    outcome = texture.bake_texture_job(request)(lambda *a: None, blender.engine.jobs.CancelToken())
    before = data_state(scene)
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        with pytest.raises(blender.engine.errors.VortxError, match="nothing was changed"):
            texture.apply_bake(obj, request, outcome)
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
    assert data_state(scene) == before


def test_the_occlusion_tolerance_follows_the_results_voxel_size(blender, capture_dir) -> None:
    import bpy

    texture = blender.vortx_blender.texture
    scene, obj = textured_scene(blender, capture_dir)
    obj[blender.vortx_blender.result.PROP_SETTINGS] = json.dumps({"voxel_size": 0.02})
    scene.vortx.voxel_size = 0.1
    request = texture.request_from_scene(scene, obj, bpy.context.evaluated_depsgraph_get())
    assert request.options.occlusion_tolerance == pytest.approx(0.04)


def test_cycles_renders_the_baked_texture(blender, capture_dir, tmp_path) -> None:
    """A Cycles render of the baked result from a capture camera, lit by a lamp at the camera, shows the
    photo's pattern (not Blender's magenta missing-texture colour, not a flat material)."""
    import bpy
    import cv2

    scene, obj = textured_scene(blender, capture_dir)
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    cameras = blender.vortx_blender.cameras
    camera = next(o for o in scene.objects if cameras.is_capture_camera(o))
    lamp = bpy.data.objects.new("flash", bpy.data.lights.new("flash", "POINT"))
    lamp.data.energy = 40.0
    lamp.matrix_world = camera.matrix_world
    scene.collection.objects.link(lamp)
    scene.camera = camera
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 8
    scene.cycles.use_denoising = False
    scene.view_settings.view_transform = "Standard"
    scene.render.resolution_percentage = 100
    scene.render.filepath = str(tmp_path / "render.png")
    bpy.ops.render.render(write_still=True)
    render = cv2.imread(str(tmp_path / "render.png"))[..., ::-1].astype(np.float64)
    photo = cv2.imread(str(camera[cameras.PROP_IMAGE]))[..., ::-1].astype(np.float64)
    assert render.shape == photo.shape
    magenta = (render[..., 0] > 200) & (render[..., 1] < 50) & (render[..., 2] > 200)
    assert magenta.mean() < 0.01 and render.std() > 5
    # The lamp's falloff changes brightness, not hue: compare the colours' chromaticity pixel by pixel.
    def chroma(image):
        return (image / np.maximum(image.sum(axis=2, keepdims=True), 1.0)).ravel()

    assert np.corrcoef(chroma(render), chroma(photo))[0, 1] > 0.8


def test_the_headset_preset_is_the_bakes_budget_and_the_panel_says_so(blender, capture_dir, engine_spy) -> None:
    import bpy

    scene, obj = textured_scene(blender, capture_dir, texture_size=1024, face_budget=0)
    texture = blender.vortx_blender.texture
    assert texture.headset_budget_text(scene) == "Desktop VR: 1024 px, all faces, PNG"
    scene.vortx.headset = "WEB"  # the Result panel's Headset menu
    assert texture.headset_budget_text(scene) == "Web: 1024 px, 50,000 faces, KTX2 ETC1S, Draco"
    scene.vortx.texture_size = 512
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    (call,) = engine_spy
    assert (call.options.texture_size, call.options.face_budget, call.options.preset) == (512, 50_000, "web")
    assert texture.bake_summary(obj)["headset"] == "web"
