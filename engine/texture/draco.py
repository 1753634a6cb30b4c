"""Draco geometry in a GLB (KHR_draco_mesh_compression) with Google's Draco through DracoPy.

Draco is the geometry compression that Blender's own glTF importer reads, as do three.js, Babylon.js,
Unity's glTFast and Cesium (meshopt, the other one, is not read by Blender). Positions are quantized to
14 bits of the room's largest side (0.6 mm in a 10 m room), texture coordinates to 14 bits (a quarter
texel of a 4096 texture), normals to 10 bits; the confidence layer is kept exactly (float). Draco may
reorder and split vertices, so the accessors' counts and bounds are those of the decoded mesh, as glTF
requires.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import VortxError
from .encoders import import_dracopy

EXTENSION = "KHR_draco_mesh_compression"
POSITION_BITS, UV_BITS, NORMAL_BITS, LEVEL = 14, 14, 10, 7
FLOAT, UNSIGNED_INT = 5126, 5125
_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3"}
_DRACO_POSITION, _DRACO_NORMAL, _DRACO_TEXCOORD = 0, 1, 3  # DracoPy attribute_type values


def draco_primitive(buffer, positions: np.ndarray, normals: np.ndarray, uvs: np.ndarray, custom: dict[str, np.ndarray],
                    faces: np.ndarray, needed_by: str) -> dict[str, Any]:
    """A glTF primitive (without material) whose geometry is one Draco buffer view in `buffer`
    (files._Buffer); its accessors carry the decoded counts and, for POSITION, the decoded bounds."""
    DracoPy = import_dracopy(needed_by)
    try:
        encoded = DracoPy.encode(
            np.ascontiguousarray(positions, np.float32), np.ascontiguousarray(faces, np.uint32),
            quantization_bits=POSITION_BITS, compression_level=LEVEL,
            normals=np.ascontiguousarray(normals, np.float64), tex_coord=np.ascontiguousarray(uvs, np.float64),
            tex_coord_quantization_bits=UV_BITS, normal_quantization_bits=NORMAL_BITS,
            generic_attributes={name: np.ascontiguousarray(values, np.float32).reshape(-1, 1)
                                for name, values in custom.items()} or None)
        decoded = DracoPy.decode(encoded)
    except Exception as error:  # DracoPy raises its own types
        raise VortxError(f"Draco could not compress the mesh: {error}") from error
    ids: dict[str, int] = {}
    accessors: dict[str, int] = {}
    for attribute in decoded.attributes:
        kind, name = attribute["attribute_type"], attribute.get("name")
        key = {_DRACO_POSITION: "POSITION", _DRACO_NORMAL: "NORMAL", _DRACO_TEXCOORD: "TEXCOORD_0"}.get(kind, name)
        if key is None:
            continue
        values = np.asarray(attribute["data"], np.float32)
        ids[key] = int(attribute["unique_id"])
        entry: dict[str, Any] = {"componentType": FLOAT, "count": int(len(values)), "type": _TYPES[values.shape[1]]}
        if key == "POSITION":
            entry["min"], entry["max"] = values.min(axis=0).tolist(), values.max(axis=0).tolist()
        buffer.accessors.append(entry)
        accessors[key] = len(buffer.accessors) - 1
    expected = {"POSITION", "NORMAL", "TEXCOORD_0", *custom}
    if set(ids) != expected:
        raise VortxError(f"Draco's decoded mesh has the attributes {sorted(ids)}, not {sorted(expected)}")
    buffer.accessors.append({"componentType": UNSIGNED_INT, "count": int(decoded.faces.size), "type": "SCALAR"})
    indices = len(buffer.accessors) - 1
    view = buffer.view(bytes(encoded))
    return {"attributes": accessors, "indices": indices,
            "extensions": {EXTENSION: {"bufferView": view, "attributes": ids}}}
