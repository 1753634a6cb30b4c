"""The sRGB transfer function and its inverse (IEC 61966-2-1), elementwise, float32.

Photos and the engine's colours are sRGB-encoded; exposure is multiplicative and blending is
physical only in linear light, so the texture bake works in linear values, and Blender's colour
attributes hold linear values too (vortx_blender/result.py).
"""

from __future__ import annotations

import numpy as np


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    c = np.asarray(values, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(values: np.ndarray) -> np.ndarray:
    """Inverse of `srgb_to_linear`; negative values clip to 0 (used instead of Blender's `color_srgb`,
    which converts through a lookup table, off by up to 1e-4)."""
    c = np.clip(np.asarray(values, dtype=np.float32), 0.0, None)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055).astype(np.float32)


# uint8 sRGB -> linear float32, as a lookup table: photos are decoded to bytes.
SRGB_BYTE_TO_LINEAR = srgb_to_linear(np.arange(256, dtype=np.float32) / 255.0)
