"""Result meshes in Blender: fast insertion with colours, decimation, Clean Up Result, and exports (PLY, OBJ,
GLB) read back in metres, Z up, with their colours. Hand-made meshes; no network runs here."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest


def bumpy_sheet(blender, n: int = 60, offset=(1.0, 2.0, 0.5)):
    """An n x n grid (2 n^2 triangles) 3 m square with smooth bumps, coloured by position, off the origin."""
    Mesh = blender.engine.mesh_io.Mesh
    ys, xs = np.mgrid[0 : n + 1, 0 : n + 1] / n
    zs = 0.3 * np.sin(3 * xs) * np.cos(2 * ys)
    vertices = (np.stack([3 * xs, 3 * ys, zs], -1).reshape(-1, 3) + offset).astype(np.float32)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    colors = np.stack([xs.ravel(), ys.ravel(), 0.5 + zs.ravel()], 1).astype(np.float32)
    return Mesh(vertices=vertices, faces=faces, normals=None, colors=colors)


def with_floater(blender, mesh):
    Mesh = blender.engine.mesh_io.Mesh
    start = len(mesh.vertices)
    return Mesh(
        vertices=np.concatenate([mesh.vertices, np.float32([[9, 9, 1], [9.1, 9, 1], [9, 9.1, 1]])]),
        faces=np.concatenate([mesh.faces, np.int32([[start, start + 1, start + 2]])]),
        colors=np.concatenate([mesh.colors, np.full((3, 3), 0.2, np.float32)]),
    )


def provenance(blender, capture="/captures/kitchen"):
    return blender.vortx_blender.result.Provenance(capture, {"voxel_size": 0.04}, "random (seed 0)", {"levels": []})


def insert(blender, scene, mesh, **kwargs):
    return blender.vortx_blender.result.insert_result(scene, mesh, provenance(blender), **kwargs)


def colours_of(mesh, prop: str = "color_srgb") -> np.ndarray:
    attribute = mesh.color_attributes["Color"]
    values = np.empty(4 * len(mesh.vertices), np.float32)
    attribute.data.foreach_get(prop, values)
    return values.reshape(-1, 4)


def positions_of(mesh) -> np.ndarray:
    values = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.attributes["position"].data.foreach_get("vector", values)
    return values.reshape(-1, 3)


def sorted_rows(array: np.ndarray) -> np.ndarray:
    array = np.asarray(array, dtype=np.float64)
    return array[np.lexsort(array.T[::-1])]


def test_insertion_is_exact_and_coloured(blender, empty_scene) -> None:
    source = bumpy_sheet(blender, n=20)
    obj = insert(blender, empty_scene, source)
    mesh = obj.data
    assert obj.name == "kitchen" and [c.name for c in obj.users_collection] == ["VoRTX Result"]
    assert not mesh.validate()  # validate() returns True when it had to fix something
    np.testing.assert_array_equal(positions_of(mesh), source.vertices)
    assert [tuple(p.vertices) for p in mesh.polygons[:3]] == [tuple(f) for f in source.faces[:3].tolist()]
    assert len(mesh.polygons) == len(source.faces) and all(p.use_smooth for p in mesh.polygons[:10])
    attribute = mesh.color_attributes["Color"]
    assert (attribute.data_type, attribute.domain) == ("FLOAT_COLOR", "POINT")
    assert mesh.color_attributes.active_color_name == "Color"
    assert mesh.color_attributes.render_color_index == mesh.color_attributes.find("Color")
    # Blender's own sRGB view of the attribute (a lookup table: within 2e-4, far below 1/255).
    np.testing.assert_allclose(colours_of(mesh)[:, :3], source.colors, atol=2e-4)
    np.testing.assert_allclose(colours_of(mesh, "color")[:, :3],
                               blender.vortx_blender.result.srgb_to_linear(source.colors), atol=1e-7)
    # The material shows the attribute.
    links = [(l.from_node.bl_idname, l.to_socket.name) for l in obj.active_material.node_tree.links]
    assert ("ShaderNodeVertexColor", "Base Color") in links


def test_srgb_conversions_match_the_standard(blender) -> None:
    module = blender.vortx_blender.result
    values = module.srgb_to_linear(np.float32([0.0, 0.04045, 0.5, 1.0]))
    np.testing.assert_allclose(values, [0.0, 0.04045 / 12.92, 0.21404114, 1.0], rtol=1e-5)
    grid = np.linspace(0, 1, 1001, dtype=np.float32)
    np.testing.assert_allclose(module.linear_to_srgb(module.srgb_to_linear(grid)), grid, atol=1e-6)


def test_mesh_arrays_read_back_what_was_inserted(blender, empty_scene) -> None:
    source = bumpy_sheet(blender, n=8)
    back = blender.vortx_blender.result.mesh_arrays(insert(blender, empty_scene, source).data)
    np.testing.assert_array_equal(back.vertices, source.vertices)
    np.testing.assert_array_equal(back.faces, source.faces)
    np.testing.assert_allclose(back.colors, source.colors, atol=1e-6)


@pytest.mark.parametrize("target", [3000, 1200])
def test_decimation_reaches_the_target_and_keeps_colours(blender, empty_scene, target: int) -> None:
    import bpy

    source = bumpy_sheet(blender, n=60)  # 7200 faces
    obj = insert(blender, empty_scene, source, target_faces=target, depsgraph=bpy.context.evaluated_depsgraph_get())
    faces = len(obj.data.polygons)
    assert abs(faces - target) <= 0.03 * target, faces
    assert all(len(p.vertices) == 3 for p in obj.data.polygons)
    assert len(obj.modifiers) == 0 and obj.data.name == "kitchen" and len(bpy.data.meshes) == 1
    attribute = obj.data.color_attributes.get("Color")
    assert attribute is not None and (attribute.data_type, attribute.domain) == ("FLOAT_COLOR", "POINT")
    assert obj.data.color_attributes.active_color_name == "Color"
    # Colours are interpolated, not lost: still spanning the sheet's gradient, close to the source
    # colour at the same place (x and y map to red and green).
    colours = colours_of(obj.data)[:, :3]
    positions = positions_of(obj.data)
    np.testing.assert_allclose(colours[:, 0], (positions[:, 0] - 1.0) / 3.0, atol=0.05)
    np.testing.assert_allclose(colours[:, 1], (positions[:, 1] - 2.0) / 3.0, atol=0.05)
    assert obj.active_material is not None


def test_clean_up_result_operator(blender, empty_scene) -> None:
    import bpy

    obj = insert(blender, empty_scene, with_floater(blender, bumpy_sheet(blender, n=30)))  # 1800 + 1 faces
    bpy.context.view_layer.objects.active = obj
    settings = empty_scene.vortx
    settings.min_piece_fraction, settings.target_faces = 0.01, 900
    assert bpy.ops.vortx.clean_result() == {"FINISHED"}
    faces = len(obj.data.polygons)
    assert abs(faces - 900) <= 27
    assert positions_of(obj.data)[:, 0].max() < 5  # the floater at x = 9 is gone
    assert obj.active_material is not None and obj.data.color_attributes.active_color_name == "Color"
    cleanups = json.loads(obj["vortx_settings"])["cleanups"]
    assert cleanups == [{"min_piece_faces": 0, "min_piece_fraction": pytest.approx(0.01), "target_faces": 900}]
    bpy.context.view_layer.objects.active = None
    assert not bpy.ops.vortx.clean_result.poll()


def test_result_name_comes_from_the_capture(blender) -> None:
    name = blender.vortx_blender.result.result_name
    assert name("/data/scans/kitchen") == "kitchen"
    assert name("/data/scans/kitchen/") == "kitchen"
    assert name("/data/scans/kitchen/transforms.json") == "kitchen"
    assert name("") == "VoRTX Result"


# --- exports -------------------------------------------------------------------------------------------------


@pytest.fixture
def exported_object(blender, empty_scene):
    source = bumpy_sheet(blender, n=12)
    return insert(blender, empty_scene, source), source


def test_ply_export_is_world_metres_z_up_with_colours(blender, exported_object, tmp_path: Path) -> None:
    obj, source = exported_object
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "room.ply")
    mesh = blender.engine.mesh_io.read_ply(path)
    assert len(mesh.vertices) == len(source.vertices) and len(mesh.faces) == len(source.faces)
    np.testing.assert_allclose(sorted_rows(mesh.vertices), sorted_rows(source.vertices), atol=1e-6)
    np.testing.assert_allclose(sorted_rows(np.hstack([mesh.vertices, mesh.colors])),
                               sorted_rows(np.hstack([source.vertices, source.colors])), atol=1 / 255 + 1e-4)
    # Within one byte step (Blender's PLY writer truncates 127.5 to 127), and not off by more on average.
    assert np.abs(sorted_rows(np.hstack([mesh.vertices, mesh.colors]))[:, 3:]
                  - sorted_rows(np.hstack([source.vertices, source.colors]))[:, 3:]).mean() < 0.6 / 255


def test_obj_export_is_world_metres_z_up_with_colours(blender, exported_object, tmp_path: Path) -> None:
    obj, source = exported_object
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "room.obj")
    rows = [line.split()[1:] for line in path.read_text().splitlines() if line.startswith("v ")]
    values = np.array(rows, dtype=np.float64)
    assert values.shape == (len(source.vertices), 6)
    expected = np.hstack([source.vertices, source.colors])
    np.testing.assert_allclose(sorted_rows(values), sorted_rows(expected), atol=2e-3)
    assert sum(line.startswith("f ") for line in path.read_text().splitlines()) == len(source.faces)


def _glb_json(path: Path) -> dict:
    data = path.read_bytes()
    magic, _, _ = struct.unpack_from("<4sII", data, 0)
    length, kind = struct.unpack_from("<I4s", data, 12)
    assert magic == b"glTF" and kind == b"JSON"
    return json.loads(data[20 : 20 + length])


def test_glb_export_reimports_to_the_same_room(blender, exported_object, tmp_path: Path) -> None:
    import bpy

    obj, source = exported_object
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "room.glb")
    document = _glb_json(path)
    (primitive,) = document["meshes"][0]["primitives"]
    assert "COLOR_0" in primitive["attributes"]
    assert document["nodes"][0]["extras"]["vortx_capture"] == "/captures/kitchen"  # provenance travels along
    before = set(bpy.data.objects)
    assert bpy.ops.import_scene.gltf(filepath=str(path)) == {"FINISHED"}
    (imported,) = set(bpy.data.objects) - before
    world = np.array([imported.matrix_world @ v.co for v in imported.data.vertices])
    np.testing.assert_allclose(world.min(axis=0), source.vertices.min(axis=0), atol=1e-5)
    np.testing.assert_allclose(world.max(axis=0), source.vertices.max(axis=0), atol=1e-5)
    attribute = imported.data.color_attributes.active_color
    assert attribute is not None and attribute.domain in ("POINT", "CORNER")
    colours = np.empty(4 * len(attribute.data), np.float32)
    attribute.data.foreach_get("color_srgb", colours)
    np.testing.assert_allclose(colours.reshape(-1, 4)[:, :3].mean(axis=0), source.colors.mean(axis=0), atol=0.01)


def test_export_keeps_the_selection_and_refuses_unknown_formats(blender, exported_object, tmp_path: Path) -> None:
    import bpy

    obj, _ = exported_object
    other = bpy.data.objects.new("other", None)
    bpy.context.scene.collection.objects.link(other)
    other.select_set(True)
    bpy.context.view_layer.objects.active = other
    blender.vortx_blender.export.export_result(obj, tmp_path / "room.ply")
    assert other.select_get() and not obj.select_get() and bpy.context.view_layer.objects.active == other
    with pytest.raises(blender.engine.errors.VortxError, match=r"use a .glb, .gltf, .ply, .obj or .usdz file name"):
        blender.vortx_blender.export.export_result(obj, tmp_path / "room.fbx")


def test_export_operator_defaults_to_glb(blender, exported_object, tmp_path: Path) -> None:
    import bpy

    obj, _ = exported_object
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.vortx.export_result(filepath=str(tmp_path / "room")) == {"FINISHED"}
    assert (tmp_path / "room.glb").is_file()
    assert bpy.ops.vortx.export_result(filepath=str(tmp_path / "room.ply")) == {"FINISHED"}
    assert (tmp_path / "room.ply").is_file()
