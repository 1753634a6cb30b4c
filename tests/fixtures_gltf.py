"""The Khronos glTF-Validator (npm gltf-validator, pinned in tools/package.json and installed by
`make test` through `make tools`) run on the GLB files the tests write.

`assert_valid_gltf(path)` fails on any error or warning, with one exception that is the validator's own
gap, not the file's: the validator does not know KHR_texture_basisu yet (KhronosGroup/glTF-Validator
issue 177), so an image of mimeType image/ktx2 draws exactly two warnings on that image
(VALUE_NOT_IN_LIST for its mimeType, IMAGE_UNRECOGNIZED_FORMAT). Those two are accepted only on images
that a texture's KHR_texture_basisu extension names, and the KTX2 bytes are then checked here instead
(KTX2 identifier, Basis Universal payload, the full mipmap chain); every other warning still fails.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
VALIDATOR = REPO / "tools" / "validate.js"
VALIDATOR_PACKAGE = REPO / "tools" / "node_modules" / "gltf-validator"
KTX2_GAP = {"VALUE_NOT_IN_LIST", "IMAGE_UNRECOGNIZED_FORMAT"}


def validator_or_skip() -> str:
    node = shutil.which("node")
    if node is None or not VALIDATOR_PACKAGE.is_dir():
        pytest.skip("the Khronos glTF-Validator is not installed: run `make tools` (needs node and npm; "
                    "`make test` runs it)")
    return node


def validate_gltf(path: Path) -> dict:
    """The validator's report of one .glb / .gltf: errors, warnings, messages (code, severity, pointer)."""
    node = validator_or_skip()
    done = subprocess.run([node, str(VALIDATOR), str(path)], capture_output=True, text=True, timeout=300)
    if not done.stdout.strip():
        raise AssertionError(f"the validator did not run on {path}: {done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _ktx2_images(path: Path) -> dict[int, bytes]:
    from fixtures_texture import read_glb

    document, binary = read_glb(path)
    named = {t["extensions"]["KHR_texture_basisu"]["source"] for t in document.get("textures", [])
             if "KHR_texture_basisu" in t.get("extensions", {})}
    images = {}
    for index in named:
        image = document["images"][index]
        view = document["bufferViews"][image["bufferView"]]
        images[index] = binary[view.get("byteOffset", 0):view.get("byteOffset", 0) + view["byteLength"]]
    return images


def check_ktx2(data: bytes) -> None:
    """A Basis Universal KTX2 file as KHR_texture_basisu requires: the KTX2 identifier, vkFormat 0
    (Basis), BasisLZ (ETC1S) or none / Zstandard (UASTC) supercompression, a full mipmap chain."""
    assert data[:12] == b"\xabKTX 20\xbb\r\n\x1a\n", "not a KTX2 file"
    words = np.frombuffer(data[12:48], "<u4")
    vk_format, width, height, levels, scheme = int(words[0]), int(words[2]), int(words[3]), int(words[7]), int(words[8])
    assert vk_format == 0 and scheme in (0, 1, 2), (vk_format, scheme)
    assert levels == int(np.log2(max(width, height))) + 1, f"{levels} mip levels for {width} x {height}"


def assert_valid_gltf(path: Path) -> dict:
    """0 errors and 0 warnings from the Khronos validator (the KTX2 gap above excepted and checked)."""
    report = validate_gltf(path)
    ktx2 = _ktx2_images(path) if path.suffix.lower() == ".glb" else {}
    gap = {f"/images/{i}" for i in ktx2} | {f"/images/{i}/mimeType" for i in ktx2}
    counted = [m for m in report["messages"] if m["severity"] <= 1
               and not (m["code"] in KTX2_GAP and m["pointer"] in gap)]
    assert report["errors"] == 0 and not counted, f"{path.name}: {json.dumps(counted, indent=1)}"
    for data in ktx2.values():
        check_ktx2(data)
    return report
