"""Textured result files: one GLB with the texture embedded, or OBJ + MTL + PNG.

GLB (glTF 2.0 binary): Y up and metres by specification, so the engine's Z-up world (x, y, z) is
written as (x, z, -y); Blender's importer turns it back. UVs have their origin at the texture's top
left in glTF, so v is flipped. The material is a plain base-colour texture (metallic 0, roughness 1)
and also declares KHR_materials_unlit: the photos already contain the room's light, so viewers that
know the extension show them as photographed, others fall back to the lit material. The confidence
layer travels as application-specific vertex attributes (`_OBSERVATIONS`, ...: glTF's rule for
custom semantics). No COLOR_0: viewers multiply the base colour by it.

OBJ keeps the engine's axes (file coordinates = world metres, Z up), like the untextured OBJ and PLY.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any, Optional

import cv2
import numpy as np

from ..errors import VortxError
from ..mesh_io import PathLike, write_obj
from .textured_mesh import TexturedMesh

MATERIAL_NAME = "VoRTX Texture"
GLB_MAGIC, GLB_VERSION = 0x46546C67, 2
CHUNK_JSON, CHUNK_BIN = 0x4E4F534A, 0x004E4942
# glTF constants
FLOAT, UNSIGNED_INT = 5126, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE = 9729, 9987, 33071


def z_up_to_y_up(xyz: np.ndarray) -> np.ndarray:
    """(N, 3) engine world (Z up) -> glTF (Y up, -Z forward): (x, y, z) -> (x, z, -y)."""
    xyz = np.asarray(xyz, np.float32)
    return np.stack([xyz[:, 0], xyz[:, 2], -xyz[:, 1]], axis=1)


def encode_png(texture: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", np.ascontiguousarray(texture[..., ::-1]))
    if not ok:
        raise VortxError("could not encode the texture as PNG")
    return data.tobytes()


class _Buffer:
    """The GLB's binary chunk, built view by view (4-byte aligned, as glTF requires)."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def view(self, payload: bytes, target: Optional[int] = None) -> int:
        self.data += b"\0" * (-len(self.data) % 4)
        entry: dict[str, Any] = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(payload)}
        if target is not None:
            entry["target"] = target
        self.data += payload
        self.views.append(entry)
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int, bounds: bool = False) -> int:
        component = UNSIGNED_INT if array.dtype == np.uint32 else FLOAT
        entry: dict[str, Any] = {"bufferView": self.view(np.ascontiguousarray(array).tobytes(), target),
                                 "componentType": component, "count": int(len(array)), "type": kind}
        if bounds:  # required for POSITION
            entry["min"] = array.min(axis=0).tolist()
            entry["max"] = array.max(axis=0).tolist()
        self.accessors.append(entry)
        return len(self.accessors) - 1


def glb_bytes(mesh: TexturedMesh, name: str = "VoRTX Result", extras: Optional[dict[str, Any]] = None) -> bytes:
    """The whole GLB file of `mesh` as bytes."""
    if len(mesh.faces) == 0:
        raise VortxError("the mesh has no faces; there is nothing to write")
    buffer = _Buffer()
    attributes = {
        "POSITION": buffer.accessor(z_up_to_y_up(mesh.vertices), "VEC3", ARRAY_BUFFER, bounds=True),
        "NORMAL": buffer.accessor(z_up_to_y_up(mesh.normals), "VEC3", ARRAY_BUFFER),
        "TEXCOORD_0": buffer.accessor(np.stack([mesh.uvs[:, 0], 1.0 - mesh.uvs[:, 1]], 1).astype(np.float32),
                                      "VEC2", ARRAY_BUFFER),
    }
    for key, values in mesh.attributes.items():
        attributes["_" + key.upper()] = buffer.accessor(np.asarray(values, np.float32).reshape(-1), "SCALAR",
                                                        ARRAY_BUFFER)
    indices = buffer.accessor(np.asarray(mesh.faces, np.uint32).reshape(-1), "SCALAR", ELEMENT_ARRAY_BUFFER)
    image_view = buffer.view(encode_png(mesh.texture))
    document: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "VoRTX for Blender"},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name, **({"extras": extras} if extras else {})}],
        "meshes": [{"name": name, "primitives": [{"attributes": attributes, "indices": indices, "material": 0}]}],
        "materials": [{"name": MATERIAL_NAME,
                       "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0,
                                                "roughnessFactor": 1.0},
                       "extensions": {"KHR_materials_unlit": {}}}],
        "textures": [{"sampler": 0, "source": 0}],
        "samplers": [{"magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR, "wrapS": CLAMP_TO_EDGE,
                      "wrapT": CLAMP_TO_EDGE}],
        "images": [{"bufferView": image_view, "mimeType": "image/png", "name": "texture"}],
        "accessors": buffer.accessors,
        "bufferViews": buffer.views,
        "buffers": [{"byteLength": len(buffer.data)}],
    }
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary = bytes(buffer.data) + b"\0" * (-len(buffer.data) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<III", GLB_MAGIC, GLB_VERSION, total) + struct.pack("<II", len(text), CHUNK_JSON) + text
            + struct.pack("<II", len(binary), CHUNK_BIN) + binary)


def write_glb(path: PathLike, mesh: TexturedMesh, name: str = "VoRTX Result",
              extras: Optional[dict[str, Any]] = None) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(glb_bytes(mesh, name, extras))
    return path


def write_textured_obj(path: PathLike, mesh: TexturedMesh) -> list[Path]:
    """`path` (.obj), its .mtl and its texture .png beside it (same stem). -> the three paths."""
    path = Path(path)
    mtl, png = path.with_suffix(".mtl"), path.with_name(path.stem + "_texture.png")
    material = "vortx_texture"
    write_obj(path, mesh.vertices, mesh.faces, normals=mesh.normals, uvs=mesh.uvs, material=(mtl.name, material))
    mtl.write_text(f"# written by VoRTX for Blender\nnewmtl {material}\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\n"
                   f"map_Kd {png.name}\n")
    png.write_bytes(encode_png(mesh.texture))
    return [path, mtl, png]


TEXTURED_SUFFIXES = (".glb", ".obj")


def write_textured(path: PathLike, mesh: TexturedMesh, extras: Optional[dict[str, Any]] = None) -> list[Path]:
    """A .glb (one file) or .obj (+ .mtl + _texture.png) by the path's suffix. -> the files written."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".glb":
        return [write_glb(path, mesh, extras=extras)]
    if suffix == ".obj":
        return write_textured_obj(path, mesh)
    raise VortxError(f"{path.name}: a textured result is written as .glb or .obj")
