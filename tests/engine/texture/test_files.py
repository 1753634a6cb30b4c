"""Textured result files: the GLB's own structure, Blender's glTF importer reading it back (metres, Z up,
texture and UVs), and the OBJ + MTL + PNG trio."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from engine.errors import VortxError
from engine.observation import ADDED
from engine.texture.files import write_glb, write_textured, write_textured_obj
from fixtures_gltf import assert_valid_gltf  # the Khronos glTF-Validator on every GLB written here
from fixtures_texture import read_glb  # an independent reader: the writer is not checked with its own code
from engine.texture.textured_mesh import TexturedMesh


def quadrant_texture(size: int = 64) -> np.ndarray:
    """Top-left red, top-right green, bottom-left blue, bottom-right white (row 0 at the top)."""
    t = np.zeros((size, size, 3), np.uint8)
    h = size // 2
    t[:h, :h] = (255, 0, 0)
    t[:h, h:] = (0, 255, 0)
    t[h:, :h] = (0, 0, 255)
    t[h:, h:] = (255, 255, 255)
    return t


def square() -> TexturedMesh:
    """A 2 x 1 m wall in the plane y = 3 (Z up), facing -y, with the whole texture on it."""
    vertices = np.array([[1, 3, 0], [3, 3, 0], [3, 3, 1], [1, 3, 1]], np.float32)
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    normals = np.tile(np.float32([0, -1, 0]), (4, 1))
    return TexturedMesh(vertices, faces, normals, uvs, quadrant_texture(),
                        attributes={"observations": np.float32([1, 2, 3, 4])}, source_vertex=np.arange(4))


def accessor(document, binary, index):
    acc = document["accessors"][index]
    view = document["bufferViews"][acc["bufferView"]]
    dtype = np.uint32 if acc["componentType"] == 5125 else np.float32
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[acc["type"]]
    data = np.frombuffer(binary, dtype, acc["count"] * width, view["byteOffset"])
    return data.reshape(acc["count"], width) if width > 1 else data


def test_glb_holds_y_up_positions_flipped_uvs_and_the_png(tmp_path):
    mesh = square()
    path = write_glb(tmp_path / "room.glb", mesh)
    assert_valid_gltf(path)
    document, binary = read_glb(path)
    primitive = document["meshes"][0]["primitives"][0]
    position = accessor(document, binary, primitive["attributes"]["POSITION"])
    np.testing.assert_allclose(position, mesh.vertices[:, [0, 2, 1]] * [1, 1, -1])  # (x, z, -y)
    np.testing.assert_allclose(document["accessors"][primitive["attributes"]["POSITION"]]["min"], position.min(0))
    uv = accessor(document, binary, primitive["attributes"]["TEXCOORD_0"])
    np.testing.assert_allclose(uv[:, 1], 1 - mesh.uvs[:, 1])  # glTF's origin is the top left
    np.testing.assert_array_equal(accessor(document, binary, primitive["indices"]), mesh.faces.ravel())
    np.testing.assert_allclose(accessor(document, binary, primitive["attributes"]["_OBSERVATIONS"]), [1, 2, 3, 4])
    assert "COLOR_0" not in primitive["attributes"]  # viewers would multiply the texture by it
    image = document["images"][0]
    view = document["bufferViews"][image["bufferView"]]
    png = binary[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
    decoded = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
    np.testing.assert_array_equal(decoded, mesh.texture)
    material = document["materials"][document["meshes"][0]["primitives"][0]["material"]]
    assert material["pbrMetallicRoughness"]["baseColorTexture"]["index"] == 0


def test_blender_imports_the_glb_in_metres_z_up_with_its_texture(tmp_path, empty_scene):
    import bpy

    mesh = square()
    path = write_glb(tmp_path / "room.glb", mesh)
    assert "FINISHED" in bpy.ops.import_scene.gltf(filepath=str(path))
    objects = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    assert len(objects) == 1
    obj = objects[0]
    data = obj.data
    world = np.array([obj.matrix_world @ v.co for v in data.vertices])
    # Same corners in Blender's world (Z up, metres); the importer may reorder or split vertices.
    for corner in mesh.vertices:
        assert np.min(np.linalg.norm(world - corner, axis=1)) < 1e-5
    # Texture: an Image Texture node with the 64 x 64 image, feeding the material.
    images = [n.image for m in data.materials for n in m.node_tree.nodes if n.type == "TEX_IMAGE" and n.image]
    assert len(images) == 1 and tuple(images[0].size) == (64, 64)
    # UVs: the corner at (1, 3, 0) has uv (0, 0) (bottom left: blue), (3, 3, 1) has (1, 1) (top right: green).
    uv_layer = data.uv_layers.active
    for loop in data.loops:
        co = np.array(obj.matrix_world @ data.vertices[loop.vertex_index].co)
        expected = mesh.uvs[np.argmin(np.linalg.norm(mesh.vertices - co, axis=1))]
        np.testing.assert_allclose(uv_layer.data[loop.index].uv, expected, atol=1e-5)
    pixels = np.array(images[0].pixels[:]).reshape(64, 64, 4)  # Blender: bottom row first
    assert pixels[0, 0, 2] > 0.9 and pixels[0, 0, 0] < 0.1  # bottom left is blue
    assert pixels[-1, -1, 1] > 0.9 and pixels[-1, -1, 0] < 0.1  # top right is green


def test_obj_mtl_png_reference_each_other(tmp_path):
    mesh = square()
    obj, mtl, png = write_textured_obj(tmp_path / "room.obj", mesh)
    lines = obj.read_text().splitlines()
    assert f"mtllib {mtl.name}" in lines and "usemtl vortx_texture" in lines
    assert sum(line.startswith("vt ") for line in lines) == 4 and "f 1/1/1 2/2/2 3/3/3" in lines
    assert f"map_Kd {png.name}" in mtl.read_text().splitlines()
    np.testing.assert_array_equal(cv2.imread(str(png))[..., ::-1], mesh.texture)


def test_write_textured_picks_the_format_by_suffix(tmp_path):
    assert [p.name for p in write_textured(tmp_path / "a.glb", square())] == ["a.glb"]
    assert_valid_gltf(tmp_path / "a.glb")
    assert [p.name for p in write_textured(tmp_path / "b.obj", square())] == ["b.obj", "b.mtl", "b_texture.png"]
    with pytest.raises(VortxError, match=".glb, .obj or .usdz"):
        write_textured(tmp_path / "c.ply", square())


def test_glb_carries_the_added_faces_mark_and_stays_valid(tmp_path):
    """A finished mesh's ADDED attribute (engine/finish) travels as the application attribute _ADDED, and
    the Khronos validator finds nothing to say about it."""
    mesh = square()
    mesh.attributes = {**mesh.attributes, ADDED: np.float32([0, 0, 1, 1])}
    path = write_glb(tmp_path / "room.glb", mesh)
    assert_valid_gltf(path)
    document, binary = read_glb(path)
    primitive = document["meshes"][0]["primitives"][0]
    np.testing.assert_allclose(accessor(document, binary, primitive["attributes"]["_" + ADDED.upper()]), [0, 0, 1, 1])
