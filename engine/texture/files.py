"""Textured result files: one GLB with the texture embedded, or OBJ + MTL + PNG.

GLB (glTF 2.0 binary): Y up and metres by specification, so the engine's Z-up world (x, y, z) is
written as (x, z, -y); Blender's importer turns it back. UVs have their origin at the texture's top
left in glTF, so v is flipped. The material is a plain base-colour texture (metallic 0, roughness 1)
and also declares KHR_materials_unlit: the photos already contain the room's light, so viewers that
know the extension show them as photographed, others fall back to the lit material. The confidence
layer travels as application-specific vertex attributes (`_OBSERVATIONS`, ...: glTF's rule for
custom semantics). No COLOR_0: viewers multiply the base colour by it.

With a headset preset (presets.py) the GLB can store its texture as KTX2 (ktx2.py, with a small PNG
fallback) and its mesh with Draco (draco.py). USDZ (usdz.py) is the Apple form of the same result.

OBJ keeps the engine's axes (file coordinates = world metres, Z up), like the untextured OBJ and PLY.

Files are written under a temporary name beside their place and renamed only when every file of the
result is complete: a failed encoder or an interrupted run leaves nothing half-written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..errors import VortxError
from ..mesh_io import PathLike, write_obj
from .draco import draco_primitive
from .encoders import model_viewer_files
from .file_parts import encode_png, glb_chunks, staged, z_up_to_y_up
from .ktx2 import glb_with_ktx2
from .options import TextureOptions
from .preview import write_preview
from .textured_mesh import TexturedMesh
from .usdz import write_usdz

MATERIAL_NAME = "VoRTX Texture"
# glTF constants
FLOAT, UNSIGNED_INT = 5126, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE = 9729, 9987, 33071


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


def glb_bytes(mesh: TexturedMesh, name: str = "VoRTX Result", extras: Optional[dict[str, Any]] = None,
              geometry: str = "none", needed_by: str = "this GLB") -> bytes:
    """The whole GLB file of `mesh` as bytes (PNG texture); geometry "draco": the mesh Draco-compressed."""
    if len(mesh.faces) == 0:
        raise VortxError("the mesh has no faces; there is nothing to write")
    buffer = _Buffer()
    positions, normals = z_up_to_y_up(mesh.vertices), z_up_to_y_up(mesh.normals)
    uvs = np.stack([mesh.uvs[:, 0], 1.0 - mesh.uvs[:, 1]], 1).astype(np.float32)
    custom = {"_" + key.upper(): np.asarray(values, np.float32).reshape(-1) for key, values in mesh.attributes.items()}
    extensions_used = ["KHR_materials_unlit"]
    primitive: dict[str, Any]
    if geometry == "draco":
        primitive = draco_primitive(buffer, positions, normals, uvs, custom, np.asarray(mesh.faces, np.uint32), needed_by)
        extensions_used.append("KHR_draco_mesh_compression")
    else:
        attributes = {
            "POSITION": buffer.accessor(positions, "VEC3", ARRAY_BUFFER, bounds=True),
            "NORMAL": buffer.accessor(normals, "VEC3", ARRAY_BUFFER),
            "TEXCOORD_0": buffer.accessor(uvs, "VEC2", ARRAY_BUFFER),
        }
        for key, values in custom.items():
            attributes[key] = buffer.accessor(values, "SCALAR", ARRAY_BUFFER)
        indices = buffer.accessor(np.asarray(mesh.faces, np.uint32).reshape(-1), "SCALAR", ELEMENT_ARRAY_BUFFER)
        primitive = {"attributes": attributes, "indices": indices}
    image_view = buffer.view(encode_png(mesh.texture))
    document: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "VoRTX for Blender"},
        "extensionsUsed": extensions_used,
        **({"extensionsRequired": ["KHR_draco_mesh_compression"]} if geometry == "draco" else {}),
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name, **({"extras": extras} if extras else {})}],
        "meshes": [{"name": name, "primitives": [{**primitive, "material": 0}]}],
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
    return glb_chunks(document, bytes(buffer.data))


def textured_glb_bytes(mesh: TexturedMesh, options: Optional[TextureOptions] = None, name: str = "VoRTX Result",
                       extras: Optional[dict[str, Any]] = None) -> bytes:
    """The GLB of `mesh` as `options` (its headset preset) asks: texture PNG or KTX2, geometry plain or Draco."""
    options = options or TextureOptions()
    needed_by = f"the '{options.preset}' headset preset"
    data = glb_bytes(mesh, name, extras, geometry=options.geometry, needed_by=needed_by)
    if options.texture_format != "png":
        data = glb_with_ktx2(data, options.texture_format, needed_by)
    return data


def write_glb(path: PathLike, mesh: TexturedMesh, name: str = "VoRTX Result",
              extras: Optional[dict[str, Any]] = None, options: Optional[TextureOptions] = None) -> Path:
    path = Path(path)
    data = textured_glb_bytes(mesh, options, name, extras)
    with staged([path]) as (temporary,):
        temporary.write_bytes(data)
    return path


def write_textured_obj(path: PathLike, mesh: TexturedMesh) -> list[Path]:
    """`path` (.obj), its .mtl and its texture .png beside it (same stem). -> the three paths."""
    path = Path(path)
    mtl, png = path.with_suffix(".mtl"), path.with_name(path.stem + "_texture.png")
    material = "vortx_texture"
    with staged([path, mtl, png]) as (obj_temp, mtl_temp, png_temp):
        write_obj(obj_temp, mesh.vertices, mesh.faces, normals=mesh.normals, uvs=mesh.uvs,
                  material=(mtl.name, material))
        mtl_temp.write_text(f"# written by VoRTX for Blender\nnewmtl {material}\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nd 1\n"
                            f"illum 1\nmap_Kd {png.name}\n")
        png_temp.write_bytes(encode_png(mesh.texture))
    return [path, mtl, png]


TEXTURED_SUFFIXES = (".glb", ".obj", ".usdz")


def write_textured(path: PathLike, mesh: TexturedMesh, extras: Optional[dict[str, Any]] = None,
                   options: Optional[TextureOptions] = None, preview: bool = False) -> list[Path]:
    """A .glb (one file; texture and geometry as `options`' headset preset asks), .obj (+ .mtl +
    _texture.png) or .usdz (Apple: PNG texture, metres, Y up) by the path's suffix; with `preview`, a
    .glb also gets the HTML preview page beside it (preview.py). -> the files written."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".glb":
        if preview:  # what the page needs is checked before anything is written
            model_viewer_files(f"the preview page of {path.name} (--preview)")
        written = [write_glb(path, mesh, extras=extras, options=options)]
        if preview:
            written += write_preview(path)
        return written
    if suffix == ".obj":
        return write_textured_obj(path, mesh)
    if suffix == ".usdz":
        return [write_usdz(path, mesh, needed_by=f"--out {path.name}")]
    raise VortxError(f"{path.name}: a textured result is written as .glb, .obj or .usdz")
