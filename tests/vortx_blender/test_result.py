"""The confidence layer in Blender: the engine's per-vertex evidence becomes mesh attributes on the
result, and the Result panel's toggle switches the shown colour between the photos and the observation
colours (red: seen by few photos; green: well observed) without touching the geometry. The displayed
colour is checked in a Workbench render, as an artist would see it in the viewport."""

from __future__ import annotations


import numpy as np
import pytest

from engine.observation import COMPLETED, OBSERVATIONS, STEREO_CONFIDENCE

GREY = 0.5  # the photo colour of the test sheet


def sheet(blender, evidence: bool = True, n: int = 10):
    """A flat 2 x 2 m sheet at z = 0, photo colour grey; its left half (x < 1) seen by one weak view, its
    right half by 8 views with confident matches."""
    Mesh = blender.engine.mesh_io.Mesh
    ys, xs = np.mgrid[0 : n + 1, 0 : n + 1] / n
    vertices = np.stack([2 * xs, 2 * ys, np.zeros_like(xs)], -1).reshape(-1, 3).astype(np.float32)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    colors = np.full((len(vertices), 3), GREY, np.float32)
    right = vertices[:, 0] >= 1.0
    attributes = {}
    if evidence:
        attributes = {OBSERVATIONS: np.where(right, 8.0, 1.0).astype(np.float32),
                      STEREO_CONFIDENCE: np.where(right, 0.95, 0.5).astype(np.float32),
                      COMPLETED: np.zeros(len(vertices), np.float32)}
    return Mesh(vertices=vertices, faces=faces, colors=colors, attributes=attributes)


def insert(blender, scene, mesh):
    results = blender.vortx_blender.result
    provenance = results.Provenance("/captures/kitchen", {"voxel_size": 0.04}, "stereo", {})
    return results.insert_result(scene, mesh, provenance)


def positions_of(mesh) -> np.ndarray:
    values = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.attributes["position"].data.foreach_get("vector", values)
    return values.reshape(-1, 3)


def float_attribute(mesh, name: str) -> np.ndarray:
    values = np.empty(len(mesh.vertices), np.float32)
    mesh.attributes[name].data.foreach_get("value", values)
    return values


def render_workbench(scene, tmp_path, name: str) -> np.ndarray:
    """(h, w, 3) sRGB 0..1 of a flat-lit Workbench render looking straight down at the sheet."""
    import bpy

    camera_data = bpy.data.cameras.new("top")
    camera_data.type = "ORTHO"
    camera_data.ortho_scale = 2.0
    camera = bpy.data.objects.get("top") or bpy.data.objects.new("top", camera_data)
    camera.data = camera_data
    if camera.name not in scene.objects:
        scene.collection.objects.link(camera)
    camera.location = (1.0, 1.0, 3.0)
    camera.rotation_euler = (0.0, 0.0, 0.0)  # looking down -Z
    scene.camera = camera
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = 16
    scene.render.resolution_percentage = 100
    scene.display.shading.light = "FLAT"
    scene.display.shading.color_type = "VERTEX"
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(tmp_path / f"{name}.png")
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(str(tmp_path / f"{name}.png"))
    pixels = np.array(image.pixels[:], np.float32).reshape(image.size[1], image.size[0], 4)[::-1, :, :3]
    bpy.data.images.remove(image)
    return pixels


def test_evidence_becomes_mesh_attributes(blender, empty_scene) -> None:
    source = sheet(blender)
    obj = insert(blender, empty_scene, source)
    mesh = obj.data
    for name, values in source.attributes.items():
        attribute = mesh.attributes[name]
        assert (attribute.data_type, attribute.domain) == ("FLOAT", "POINT")
        np.testing.assert_array_equal(float_attribute(mesh, name), values)
    assert blender.vortx_blender.result.has_observation(mesh)
    # The photos are what a new result shows.
    assert mesh.color_attributes.active_color_name == "Color"
    assert mesh.color_attributes.render_color_index == mesh.color_attributes.find("Color")
    assert not getattr(obj, "vortx_show_observation")
    # Clean Result and the exporters read the arrays back with the evidence.
    arrays = blender.vortx_blender.result.mesh_arrays(mesh)
    assert set(arrays.attributes) == set(source.attributes)
    np.testing.assert_array_equal(arrays.attributes[OBSERVATIONS], source.attributes[OBSERVATIONS])


def test_toggle_switches_the_shown_colour_and_not_the_geometry(blender, empty_scene, tmp_path) -> None:
    obj = insert(blender, empty_scene, sheet(blender))
    mesh = obj.data
    before = positions_of(mesh).copy()
    photo = render_workbench(empty_scene, tmp_path, "photo")
    np.testing.assert_allclose(photo[4:12, 2:14], GREY, atol=0.03)  # the grey photo colour everywhere

    obj.vortx_show_observation = True  # the update callback does the switch, as the panel's checkbox would
    assert mesh.color_attributes.active_color_name == "Observation"
    assert mesh.color_attributes.render_color_index == mesh.color_attributes.find("Observation")
    assert obj.active_material.name == "VoRTX Observation Colour"
    layer_names = {n.layer_name for n in obj.active_material.node_tree.nodes if n.bl_idname == "ShaderNodeVertexColor"}
    assert layer_names == {"Observation"}
    shown = render_workbench(empty_scene, tmp_path, "observation")
    left, right = shown[4:12, 1:6].reshape(-1, 3).mean(0), shown[4:12, 10:15].reshape(-1, 3).mean(0)
    assert left[0] > 0.6 and left[1] < 0.35  # one weak view: red
    assert right[1] > 0.6 and right[0] < 0.35  # eight confident views: green
    np.testing.assert_array_equal(positions_of(obj.data), before)

    obj.vortx_show_observation = False
    assert mesh.color_attributes.active_color_name == "Color"
    assert obj.active_material.name == "VoRTX Vertex Colour"
    np.testing.assert_allclose(render_workbench(empty_scene, tmp_path, "back"), photo, atol=1e-3)


def test_a_result_without_evidence_keeps_its_photo_colours(blender, empty_scene) -> None:
    obj = insert(blender, empty_scene, sheet(blender, evidence=False))
    assert not blender.vortx_blender.result.has_observation(obj.data)
    obj.vortx_show_observation = True
    assert obj.data.color_attributes.active_color_name == "Color"
    assert obj.active_material.name == "VoRTX Vertex Colour"


def test_decimation_and_clean_up_keep_the_layer_and_the_toggle(blender, empty_scene) -> None:
    import bpy

    results = blender.vortx_blender.result
    obj = insert(blender, empty_scene, sheet(blender, n=30))
    obj.vortx_show_observation = True
    results.decimate(obj, 600, bpy.context.evaluated_depsgraph_get())
    assert len(obj.data.polygons) < 1800
    assert obj.data.color_attributes.active_color_name == "Observation"
    observations = float_attribute(obj.data, OBSERVATIONS)
    x = positions_of(obj.data)[:, 0]
    assert np.all(observations[x < 0.9] < 1.5) and np.all(observations[x > 1.1] > 7.5)  # interpolated, not lost
    arrays = results.mesh_arrays(obj.data)
    results.replace_mesh(obj, arrays)
    assert set(results.vertex_attributes(obj.data)) == {OBSERVATIONS, STEREO_CONFIDENCE, COMPLETED}
    assert obj.data.color_attributes.active_color_name == "Observation"


class Recorder:
    """Records the UILayout calls of draw_result_settings (the full checking recorder is tests/fixtures_blender_ui.py)."""

    def __init__(self, calls: list) -> None:
        self.calls = calls

    def __getattr__(self, name: str):
        def call(*args, **kwargs):
            self.calls.append((name, args, kwargs))
            return Recorder(self.calls)

        return call


@pytest.mark.parametrize("evidence", [True, False])
def test_result_panel_offers_the_toggle_for_the_shown_result(blender, empty_scene, evidence: bool) -> None:
    import bpy

    obj = insert(blender, empty_scene, sheet(blender, evidence=evidence))
    results = blender.vortx_blender.result
    assert results.shown_result(empty_scene, None) == obj
    assert "vortx_show_observation" in bpy.types.Object.bl_rna.properties
    calls: list = []
    blender.ui.panels.draw_result_settings(Recorder(calls), empty_scene.vortx, results.shown_result(empty_scene, None))
    props = [c for c in calls if c[0] == "prop" and c[1] and c[1][0] == obj]
    labels = [c for c in calls if c[0] == "label" and "observation" in c[2].get("text", "")]
    assert (len(props), len(labels)) == ((1, 0) if evidence else (0, 1))
    if evidence:
        assert props[0][1][1] == "vortx_show_observation"


def test_export_writes_photo_colours_while_the_observation_is_shown(blender, empty_scene, tmp_path) -> None:
    """Exporters write the shown colour attribute; the file must carry the photos' colours, and the
    viewport must still show the observation afterwards."""
    obj = insert(blender, empty_scene, sheet(blender))
    obj.vortx_show_observation = True
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "sheet.ply")
    written = blender.engine.mesh_io.read_ply(path)
    np.testing.assert_allclose(written.colors, GREY, atol=0.01)
    assert obj.data.color_attributes.active_color_name == "Observation" and obj.vortx_show_observation


def test_faces_the_finishing_added_are_a_selectable_face_attribute(blender, empty_scene) -> None:
    """The engine's ADDED vertex attribute (1 on faces added where no photo saw surface) becomes a BOOLEAN
    face attribute, active, true exactly on the faces whose three corners are added (here: the sheet's
    faces with x < 1, computed from the sheet's own layout)."""
    mesh = sheet(blender, evidence=False)
    added = (mesh.vertices[:, 0] <= 1.0).astype(np.float32)
    mesh.attributes = {blender.engine.observation.ADDED: added}
    obj = insert(blender, empty_scene, mesh)
    attribute = obj.data.attributes[blender.vortx_blender.result.ADDED_FACES_ATTRIBUTE]
    assert (attribute.domain, attribute.data_type) == ("FACE", "BOOLEAN")
    assert obj.data.attributes.active.name == attribute.name
    values = np.zeros(len(obj.data.polygons), bool)
    attribute.data.foreach_get("value", values)
    centres = np.array([p.center[:] for p in obj.data.polygons])
    np.testing.assert_array_equal(values, centres[:, 0] < 1.0)


def test_a_ply_export_keeps_the_added_mark_for_the_texture_bake(blender, empty_scene, tmp_path) -> None:
    """`engine texture` reads the exported PLY: the ADDED vertex attribute must travel with it, so the
    bake can fill the added faces from their plane (the batch exports, then bakes)."""
    mesh = sheet(blender, evidence=False)
    added = (mesh.vertices[:, 0] <= 1.0).astype(np.float32)
    mesh.attributes = {blender.engine.observation.ADDED: added}
    obj = insert(blender, empty_scene, mesh)
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "sheet.ply")
    written = blender.engine.mesh_io.read_ply(path)
    name = blender.engine.observation.ADDED
    assert name in written.attributes
    by_position = {tuple(np.round(v, 4)): a for v, a in zip(written.vertices, written.attributes[name])}
    expected = {tuple(np.round(v, 4)): a for v, a in zip(mesh.vertices, added)}
    assert by_position == expected
