"""Exporting a baked (textured) result: GLB/glTF carry the UVs and the photo texture and no vertex
colours, OBJ a .mtl and the texture beside it; an untextured result exports its vertex colours as
before. Files are read back with an own GLB/OBJ parser and with Blender's glTF importer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fixtures_gltf import assert_valid_gltf  # the Khronos glTF-Validator on Blender's export
from fixtures_texture import (decode_png, glb_base_colour_png, image_rows_top_first, make_box_capture, read_glb,
                              textured_scene)


@pytest.fixture(scope="module")
def capture_dir(blender, tmp_path_factory) -> Path:
    return make_box_capture(blender, tmp_path_factory.mktemp("export") / "box_room")


@pytest.fixture
def baked(blender, capture_dir):
    """A scene with the baked box room; -> (scene, object, the engine's texture (H, W, 3) top row first)."""
    import bpy

    scene, obj = textured_scene(blender, capture_dir)
    assert bpy.ops.vortx.bake_texture() == {"FINISHED"}
    image = blender.vortx_blender.result.texture_image_of(obj.active_material)
    return scene, obj, image_rows_top_first(image)


def test_glb_of_a_textured_result_has_uvs_and_the_photo_texture(blender, baked, tmp_path) -> None:
    scene, obj, texture = baked
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "room.glb", scene.view_layers[0])
    assert_valid_gltf(path)
    document, binary = read_glb(path)
    (primitive,) = document["meshes"][0]["primitives"]
    assert "TEXCOORD_0" in primitive["attributes"]
    assert not any(name.startswith("COLOR_") for name in primitive["attributes"])  # would tint the texture
    (material,) = document["materials"]
    pbr = material["pbrMetallicRoughness"]
    assert pbr.get("metallicFactor", 1.0) == 0.0 and pbr.get("roughnessFactor", 1.0) == 1.0
    np.testing.assert_array_equal(decode_png(glb_base_colour_png(document, binary)), texture)  # lossless PNG
    # glTF counts v from the top: the exported UVs are Blender's with v flipped, as many as the corners.
    accessor = document["accessors"][primitive["attributes"]["TEXCOORD_0"]]
    assert accessor["type"] == "VEC2" and accessor["componentType"] == 5126  # float
    view = document["bufferViews"][accessor["bufferView"]]
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    exported = np.frombuffer(binary, np.float32, 2 * accessor["count"], start).reshape(-1, 2)
    blender_uvs = np.empty(2 * len(obj.data.loops), np.float32)
    obj.data.uv_layers["UVMap"].data.foreach_get("uv", blender_uvs)
    flipped = blender_uvs.reshape(-1, 2) * np.float32([1, -1]) + np.float32([0, 1])
    for ours, theirs in ((exported, flipped), (flipped, exported)):  # the same UVs (the exporter dedups corners)
        assert cKDTree(theirs).query(ours)[0].max() < 1e-6


def test_glb_imports_back_into_blender_with_its_texture(blender, baked, tmp_path) -> None:
    import bpy

    scene, obj, texture = baked
    faces = len(obj.data.polygons)
    lowest, highest = (np.array([min(v.co[i] for v in obj.data.vertices) for i in range(3)]),
                       np.array([max(v.co[i] for v in obj.data.vertices) for i in range(3)]))
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "room.glb", scene.view_layers[0])

    bpy.ops.wm.read_homefile(use_empty=True)
    assert bpy.ops.import_scene.gltf(filepath=str(path)) == {"FINISHED"}
    (imported,) = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    mesh = imported.data
    assert len(mesh.polygons) == faces and len(mesh.uv_layers) == 1
    assert len(mesh.color_attributes) == 0
    (node,) = [n for n in imported.active_material.node_tree.nodes if n.type == "TEX_IMAGE"]
    assert tuple(node.image.size) == (512, 512)
    np.testing.assert_array_equal(image_rows_top_first(node.image), texture)
    # The same room in the same place (glTF's Y up converted back to Z up).
    coords = np.array([imported.matrix_world @ v.co for v in mesh.vertices])
    np.testing.assert_allclose(coords.min(0), lowest, atol=1e-5)
    np.testing.assert_allclose(coords.max(0), highest, atol=1e-5)
    uvs = np.empty(2 * len(mesh.loops), np.float32)
    mesh.uv_layers[0].data.foreach_get("uv", uvs)
    assert uvs.min() >= 0.0 and uvs.max() <= 1.0 and np.ptp(uvs) > 0.5


def test_obj_of_a_textured_result_writes_mtl_and_texture(blender, baked, tmp_path) -> None:
    scene, obj, texture = baked
    image = blender.vortx_blender.result.texture_image_of(obj.active_material)
    filepath = image.filepath_raw
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "out" / "room.obj", scene.view_layers[0])
    assert image.filepath_raw == filepath and image.packed_file is not None  # the .blend keeps its own texture
    lines = path.read_text().splitlines()
    assert sum(line.startswith("vt ") for line in lines) > 0
    assert sum(line.startswith("f ") for line in lines) == len(obj.data.polygons)
    (mtllib,) = [line.split(maxsplit=1)[1] for line in lines if line.startswith("mtllib ")]
    mtl = (path.parent / mtllib).read_text().splitlines()
    (map_kd,) = [line.split(maxsplit=1)[1] for line in mtl if line.startswith("map_Kd")]
    picture = path.parent / map_kd.strip().strip('"')
    assert picture.name == "room_texture.png" and picture.is_file()
    np.testing.assert_array_equal(decode_png(picture.read_bytes()), texture)


def test_untextured_result_exports_vertex_colours_as_before(blender, capture_dir, tmp_path) -> None:
    scene, obj = textured_scene(blender, capture_dir)  # not baked
    assert not blender.vortx_blender.result.is_textured(obj)
    document, _ = read_glb(blender.vortx_blender.export.export_result(obj, tmp_path / "room.glb", scene.view_layers[0]))
    attributes = document["meshes"][0]["primitives"][0]["attributes"]
    assert "COLOR_0" in attributes and "TEXCOORD_0" not in attributes and "images" not in document
    obj_path = blender.vortx_blender.export.export_result(obj, tmp_path / "room.obj", scene.view_layers[0])
    assert not any(line.startswith(("vt ", "mtllib")) for line in obj_path.read_text().splitlines())


def test_export_while_showing_observation_writes_the_texture(blender, baked, tmp_path) -> None:
    results = blender.vortx_blender.result
    scene, obj, texture = baked
    obj.vortx_show_observation = True
    document, _ = read_glb(blender.vortx_blender.export.export_result(obj, tmp_path / "room.glb", scene.view_layers[0]))
    assert "baseColorTexture" in document["materials"][0]["pbrMetallicRoughness"]
    principled = next(n for n in obj.active_material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    assert principled.inputs["Base Color"].links[0].from_node.name == results.TEXTURE_OBSERVATION_NODE  # shown again


def test_glb_carries_the_confidence_layer(blender, baked, tmp_path) -> None:
    """The textured result's confidence attributes travel as glTF custom attributes (as in the engine's
    GLB), with the values the mesh holds; the mesh itself is left without the export's copies."""
    scene, obj, _ = baked
    names_before = sorted(a.name for a in obj.data.attributes)
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "room.glb", scene.view_layers[0])
    assert sorted(a.name for a in obj.data.attributes) == names_before
    document, binary = read_glb(path)
    (primitive,) = document["meshes"][0]["primitives"]
    accessor = document["accessors"][primitive["attributes"]["_OBSERVATIONS"]]
    view = document["bufferViews"][accessor["bufferView"]]
    exported = np.frombuffer(binary, np.float32, accessor["count"], view.get("byteOffset", 0) + accessor.get("byteOffset", 0))
    values = np.empty(len(obj.data.vertices), np.float32)
    obj.data.attributes["observations"].data.foreach_get("value", values)
    assert set(np.unique(exported)) == set(np.unique(values)) and {"_STEREO_CONFIDENCE", "_COMPLETED"} <= set(primitive["attributes"])


def test_glb_for_a_standalone_headset_has_draco_and_ktx2_and_passes_the_validator(blender, baked, tmp_path) -> None:
    import bpy

    scene, obj, texture = baked
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "room.glb", scene.view_layers[0],
                                                      headset="standalone")
    assert_valid_gltf(path)  # the KTX2 image checked by the fixture itself (the validator does not know it yet)
    document, binary = read_glb(path)
    (primitive,) = document["meshes"][0]["primitives"]
    assert "KHR_draco_mesh_compression" in primitive["extensions"]
    assert "KHR_texture_basisu" in document["textures"][0]["extensions"]
    assert [p.name for p in tmp_path.iterdir()] == ["room.glb"]  # no temporary file left
    faces = len(obj.data.polygons)
    bpy.ops.wm.read_homefile(use_empty=True)
    assert "FINISHED" in bpy.ops.import_scene.gltf(filepath=str(path))  # Blender reads its own Draco back
    (imported,) = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    assert len(imported.data.polygons) == faces


def test_usdz_export_opens_in_usd_with_its_texture_in_metres(blender, baked, tmp_path) -> None:
    from pxr import Ar, Usd, UsdGeom, UsdShade

    scene, obj, texture = baked
    path = blender.vortx_blender.export.export_result(obj, tmp_path / "room.usdz", scene.view_layers[0])
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    (mesh,) = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    world = UsdGeom.Xformable(mesh).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
    points = np.array([world.Transform(p) for p in mesh.GetPointsAttr().Get()])
    assert np.ptp(points, axis=0) == pytest.approx([3.0, 2.5, 3.0], abs=0.01)  # the 3 x 3 x 2.5 m room, Y up
    material, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
    files = [UsdShade.Shader(p).GetInput("file").Get() for p in Usd.PrimRange(material.GetPrim())
             if p.IsA(UsdShade.Shader) and UsdShade.Shader(p).GetIdAttr().Get() == "UsdUVTexture"]
    assert len(files) == 1
    data = bytes(Ar.GetResolver().OpenAsset(Ar.ResolvedPath(files[0].resolvedPath)).GetBuffer())
    assert decode_png(data).shape == texture.shape
