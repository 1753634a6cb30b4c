"""What every textured result file is written with: the staged write (temporary names, renamed only when
every file is complete), PNG encoding, glTF's axes and the GLB container's chunks.

The bottom of the file writers: files.py (GLB, OBJ), ktx2.py, usdz.py and preview.py build on it, and
files.py on them, so the imports go one way.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np

from ..errors import VortxError

GLB_MAGIC, GLB_VERSION = 0x46546C67, 2
CHUNK_JSON, CHUNK_BIN = 0x4E4F534A, 0x004E4942


def z_up_to_y_up(xyz: np.ndarray) -> np.ndarray:
    """(N, 3) engine world (Z up) -> glTF (Y up, -Z forward): (x, y, z) -> (x, z, -y)."""
    xyz = np.asarray(xyz, np.float32)
    return np.stack([xyz[:, 0], xyz[:, 2], -xyz[:, 1]], axis=1)


def encode_png(texture: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", np.ascontiguousarray(texture[..., ::-1]))
    if not ok:
        raise VortxError("could not encode the texture as PNG")
    return data.tobytes()


def glb_chunks(document: dict[str, Any], binary: bytes) -> bytes:
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary = binary + b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<III", GLB_MAGIC, GLB_VERSION, total) + struct.pack("<II", len(text), CHUNK_JSON) + text
            + struct.pack("<II", len(binary), CHUNK_BIN) + binary)


def unpack_glb(data: bytes) -> tuple[dict[str, Any], bytes]:
    """(the glTF JSON, the binary chunk) of GLB bytes."""
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != GLB_VERSION or length != len(data):
        raise VortxError("not a glTF 2.0 binary (GLB) file, or a truncated one")
    json_length, json_type = struct.unpack_from("<II", data, 12)
    document = json.loads(data[20:20 + json_length])
    offset = 20 + json_length
    if offset >= len(data):
        return document, b""
    bin_length, bin_type = struct.unpack_from("<II", data, offset)
    if bin_type != CHUNK_BIN:
        raise VortxError("the GLB's second chunk is not its binary buffer")
    return document, data[offset + 8:offset + 8 + bin_length]


def pack_glb(document: dict[str, Any], views: list[bytes]) -> bytes:
    """GLB bytes of `document` with its buffer views' contents `views` laid out again in order (4-byte
    aligned) in the one binary buffer."""
    data = bytearray()
    for entry, payload in zip(document["bufferViews"], views):
        data += b"\0" * (-len(data) % 4)
        entry["buffer"], entry["byteOffset"], entry["byteLength"] = 0, len(data), len(payload)
        data += payload
    document["buffers"] = [{"byteLength": len(data)}]
    return glb_chunks(document, bytes(data))


@contextmanager
def staged(paths: list[Path]) -> Iterator[list[Path]]:
    """Temporary paths beside `paths` to write into; renamed onto them only when the block finishes,
    removed when it fails (nothing half-written is left)."""
    paths = [Path(p) for p in paths]
    for path in paths:
        path.parent.mkdir(parents=True, exist_ok=True)
    temporary = [p.with_name(f".{p.name}.{os.getpid()}.partial") for p in paths]
    try:
        yield temporary
        for source, target in zip(temporary, paths):
            if not source.exists():
                raise VortxError(f"{target.name} was not written")
        for source, target in zip(temporary, paths):
            os.replace(source, target)
    finally:
        for source in temporary:
            if source.is_dir():
                shutil.rmtree(source, ignore_errors=True)
            else:
                source.unlink(missing_ok=True)
