"""Photometric augmentation of a training crop: two of five ops, the same for every view of the crop
(vortx-spec.md section 2), plus optional Gaussian sensor noise. Geometric augmentation (rotation,
mirror) changes poses and targets too, so it lives with the crop (crops.py)."""

from __future__ import annotations

import numpy as np

PHOTOMETRIC_OPS = ("brightness", "contrast", "saturation", "hue", "blur")


def sample_photometric(rng: np.random.Generator, noise: float = 0.0) -> list[tuple[str, float]]:
    """Two of the five ops with their parameters, plus sensor noise with p = 0.5 when enabled."""
    ops = []
    for i in rng.choice(len(PHOTOMETRIC_OPS), size=2, replace=False):
        name = PHOTOMETRIC_OPS[int(i)]
        if name in ("brightness", "contrast", "saturation"):
            ops.append((name, float(rng.uniform(0.5, 1.5))))
        elif name == "hue":
            ops.append((name, float(rng.uniform(-0.05, 0.05))))
        else:
            ops.append((name, float(rng.choice([1.0, 2.0, 3.0]))))
    if noise > 0 and rng.random() < 0.5:
        ops.append(("noise", float(rng.uniform(0.0, noise))))
    return ops


def apply_photometric(images: np.ndarray, ops: list[tuple[str, float]], rng: np.random.Generator) -> np.ndarray:
    """Apply ops to (V, H, W, 3) uint8 RGB; returns float32 0-255."""
    import cv2  # defers cv2 (OpenCV) off the light paths

    x = images.astype(np.float32)
    for name, p in ops:
        gray = (x @ np.array([0.299, 0.587, 0.114], dtype=np.float32))[..., None]
        if name == "brightness":
            x = x * p
        elif name == "contrast":
            x = (x - gray.mean(axis=(1, 2, 3), keepdims=True)) * p + gray.mean(axis=(1, 2, 3), keepdims=True)
        elif name == "saturation":
            x = gray + (x - gray) * p
        elif name == "hue":
            out = []
            for img in np.clip(x, 0, 255).astype(np.uint8):
                hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV_FULL).astype(np.int32)
                hsv[..., 0] = (hsv[..., 0] + int(round(p * 256))) % 256
                out.append(cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB_FULL))
            x = np.stack(out).astype(np.float32)
        elif name == "blur":
            x = np.stack([cv2.GaussianBlur(img, (7, 7), p) for img in x])
        elif name == "noise":
            x = x + rng.normal(0.0, p, size=x.shape).astype(np.float32)
        x = np.clip(x, 0, 255)
    return x
