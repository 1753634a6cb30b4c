"""Helpers for the Bake Texture tests (tests/vortx_blender, tests/operators, tests/scripts): the
engine's synthetic box room as a capture, a hand-made result mesh of that room, a scene holding both,
and readers for what a textured export holds (GLB chunks, PNG bytes, a Blender image's rows).

The scene: the box room's cameras as Import Capture makes them, and a result mesh of the room's walls,
floor and ceiling (a 6 x 6 grid each) with colours and the confidence layer; baked at 512 texels with
a 200-face budget (under a second).
"""

from __future__ import annotations

import importlib
import json
import struct
from pathlib import Path

import cv2
import numpy as np

from engine.observation import COMPLETED, OBSERVATIONS, STEREO_CONFIDENCE

ROOM = (3.0, 3.0, 2.5)
SMALL = {"texture_size": 512, "face_budget": 200}


def make_box_capture(blender, path: Path) -> Path:
    """The engine's synthetic box room: 6 posed photos of 96 x 72 in the ScanNet layout at `path`."""
    synthetic = importlib.import_module(f"{blender.__name__}.engine.recon.synthetic")
    synthetic.make_synthetic_capture(path, room_size=ROOM, frames=6, image_size=(96, 72))
    return path


def room_mesh(blender, n: int = 6, evidence: bool = True):
    """The room box's six sides, each an n x n grid of triangle pairs; colours vary with height, the
    confidence layer with x (seen well on the x > 1.5 half)."""
    Mesh = blender.engine.mesh_io.Mesh
    vertices, faces = [], []
    sides = [((0, 0, 0), (ROOM[0], 0, 0), (0, ROOM[1], 0)), ((0, 0, ROOM[2]), (0, ROOM[1], 0), (ROOM[0], 0, 0)),
             ((0, 0, 0), (0, 0, ROOM[2]), (ROOM[0], 0, 0)), ((0, ROOM[1], 0), (ROOM[0], 0, 0), (0, 0, ROOM[2])),
             ((0, 0, 0), (0, ROOM[1], 0), (0, 0, ROOM[2])), ((ROOM[0], 0, 0), (0, 0, ROOM[2]), (0, ROOM[1], 0))]
    for origin, u, v in sides:
        base = len(vertices)
        for j in range(n + 1):
            for i in range(n + 1):
                vertices.append(np.add(origin, np.multiply(u, i / n) + np.multiply(v, j / n)))
        for j in range(n):
            for i in range(n):
                a = base + j * (n + 1) + i
                faces += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    vertices = np.asarray(vertices, np.float32)
    colors = np.stack([vertices[:, 2] / ROOM[2], np.full(len(vertices), 0.4), 1 - vertices[:, 2] / ROOM[2]], 1)
    attributes = {}
    if evidence:
        good = vertices[:, 0] > 1.5
        attributes = {OBSERVATIONS: np.where(good, 8.0, 1.0).astype(np.float32),
                      STEREO_CONFIDENCE: np.where(good, 0.9, 0.4).astype(np.float32),
                      COMPLETED: np.zeros(len(vertices), np.float32)}
    return Mesh(vertices=vertices, faces=np.asarray(faces, np.int32), colors=colors.astype(np.float32),
                attributes=attributes)


def textured_scene(blender, capture_dir: Path, evidence: bool = True, **settings):
    """A fresh scene: the capture cameras, the result `box_room`, the small bake settings."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    capture = blender.engine.capture.load_capture(capture_dir)
    blender.vortx_blender.capture.apply_capture(scene, capture, capture_dir)
    results = blender.vortx_blender.result
    provenance = results.Provenance(str(capture_dir), {"voxel_size": 0.04}, "stereo", {})
    obj = results.insert_result(scene, room_mesh(blender, evidence=evidence), provenance)
    for name, value in {**SMALL, **settings}.items():
        setattr(scene.vortx, name, value)
    bpy.context.view_layer.update()
    return scene, obj


def image_rows_top_first(image) -> np.ndarray:
    """(h, w, 3) uint8 of a Blender image, row 0 at the top (as the engine and PNG store it)."""
    width, height = image.size
    pixels = np.empty(width * height * 4, np.float32)
    image.pixels.foreach_get(pixels)
    return np.round(pixels.reshape(height, width, 4)[::-1, :, :3] * 255).astype(np.uint8)


def read_glb(path: Path) -> tuple[dict, bytes]:
    """(the glTF JSON, the binary chunk) of a .glb file (glTF 2.0 section 4.4)."""
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and length == len(data)
    json_length, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON"
    document = json.loads(data[20:20 + json_length])
    offset = 20 + json_length
    bin_length, bin_type = struct.unpack_from("<I4s", data, offset)
    assert bin_type == b"BIN\x00"
    return document, data[offset + 8:offset + 8 + bin_length]


def decode_png(data: bytes) -> np.ndarray:
    """(H, W, 3) uint8 RGB of PNG bytes."""
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def glb_base_colour_png(document: dict, binary: bytes) -> bytes:
    """The PNG bytes of the first material's base colour texture in a GLB (embedded in the binary chunk)."""
    pbr = document["materials"][0]["pbrMetallicRoughness"]
    image = document["images"][document["textures"][pbr["baseColorTexture"]["index"]]["source"]]
    assert image["mimeType"] == "image/png"
    view = document["bufferViews"][image["bufferView"]]
    start = view.get("byteOffset", 0)
    return binary[start:start + view["byteLength"]]
