"""Headset presets: named budgets for the textured result (faces, texture size, texture and geometry
compression), one per kind of device that loads it.

A preset is a budget: it caps the texture size and the face budget (a smaller --texture-size or
--face-budget still wins) and picks how the GLB stores the texture and the geometry:

- texture "png": the texture as PNG (decoded to 4 bytes per texel on the GPU, plus a third for mipmaps);
  "ktx2-etc1s" / "ktx2-uastc": KTX2 / Basis Universal (`KHR_texture_basisu`) that the GPU keeps
  compressed: ETC1S is small on disk and transcodes to 0.5 byte per texel (ETC1/ETC2 RGB, BC1), UASTC
  keeps more detail at 1 byte per texel (ASTC 4x4, BC7). A small PNG (a quarter of the side) stays in the
  file as the fallback for viewers without the extension (Blender's importer), so the file opens everywhere.
- geometry "draco": `KHR_draco_mesh_compression`, read by three.js, Babylon.js, Unity glTFast, Cesium and
  Blender's own importer (meshopt, the other choice, is not read by Blender's importer; Godot reads neither).

USDZ (Apple) always carries a PNG texture: KTX2 is not a USDZ texture format.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..errors import VortxError
from .options import GEOMETRY_COMPRESSIONS, TEXTURE_FORMATS, TextureOptions

__all__ = ["GEOMETRY_COMPRESSIONS", "TEXTURE_FORMATS", "PRESETS", "PRESET_NAMES", "HeadsetPreset", "with_preset"]

# GPU bytes per texel of each texture format once loaded (before mipmaps), and the format the GPU holds.
GPU_BYTES_PER_TEXEL = {"png": 4.0, "ktx2-etc1s": 0.5, "ktx2-uastc": 1.0}
GPU_FORMAT = {"png": "RGBA8 (PNG decoded)", "ktx2-etc1s": "ETC1/ETC2 RGB or BC1 (transcoded from ETC1S)",
              "ktx2-uastc": "ASTC 4x4 or BC7 (transcoded from UASTC)"}
MIPMAP_FACTOR = 4.0 / 3.0  # a full mipmap chain adds a third


@dataclass(frozen=True)
class HeadsetPreset:
    name: str
    label: str
    device: str  # what it is for, one phrase
    texture_size: int  # the cap on the texture side
    face_budget: int  # the cap on the faces (0 = no cap)
    texture_format: str
    geometry: str


PRESETS: dict[str, HeadsetPreset] = {p.name: p for p in (
    HeadsetPreset("desktop", "Desktop VR", "PC VR (SteamVR, Quest Link) and offline use", 8192, 0, "png", "none"),
    HeadsetPreset("standalone", "Standalone Headset", "Quest, Pico: mobile GPU, 2048 px, compressed on the GPU",
                  2048, 100_000, "ktx2-etc1s", "draco"),
    HeadsetPreset("vision-pro", "Vision Pro", "Apple Vision Pro (GLB with UASTC; write .usdz for visionOS apps)",
                  4096, 150_000, "ktx2-uastc", "draco"),
    HeadsetPreset("web", "Web", "browsers and headset browsers: the smallest download", 2048, 50_000, "ktx2-etc1s",
                  "draco"),
)}
PRESET_NAMES = tuple(PRESETS)
DEFAULT_PRESET = "desktop"


def preset(name: str) -> HeadsetPreset:
    try:
        return PRESETS[name]
    except KeyError:
        raise VortxError(f"unknown headset preset {name!r}: use one of {', '.join(PRESET_NAMES)}") from None


def with_preset(options: TextureOptions, name: str) -> TextureOptions:
    """`options` within the preset's budget (texture size and faces capped) with its file formats."""
    chosen = preset(name)
    faces = options.face_budget
    if chosen.face_budget:
        faces = chosen.face_budget if faces == 0 else min(faces, chosen.face_budget)
    return replace(options, texture_size=min(options.texture_size, chosen.texture_size), face_budget=faces,
                   texture_format=chosen.texture_format, geometry=chosen.geometry, preset=chosen.name)


def gpu_texture_bytes(width: int, height: int, texture_format: str, mipmaps: bool = True) -> int:
    """The GPU memory a texture of this size takes once loaded (the mipmap chain included)."""
    return int(round(width * height * GPU_BYTES_PER_TEXEL[texture_format] * (MIPMAP_FACTOR if mipmaps else 1.0)))


def preset_table_lines() -> list[str]:
    """One line per preset, for --help and the README."""
    return [f"{p.name}: {p.texture_size} px, {'no face cap' if not p.face_budget else f'{p.face_budget:,} faces'}, "
            f"texture {p.texture_format}, geometry {p.geometry} ({p.device})" for p in PRESETS.values()]
