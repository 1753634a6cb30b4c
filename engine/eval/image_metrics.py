"""Image similarity over a region: PSNR and SSIM of uint8 RGB images on the pixels of a mask
(a render against the photo it should reproduce, over the pixels the render covers)."""

from __future__ import annotations

import numpy as np

from ..errors import VortxError

PEAK = 255.0


def _checked(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    a, b, mask = np.asarray(a), np.asarray(b), np.asarray(mask, bool)
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3:
        raise VortxError(f"images must both be (h, w, 3) RGB, got {a.shape} and {b.shape}")
    if mask.shape != a.shape[:2]:
        raise VortxError(f"mask {mask.shape} does not match the images' {a.shape[:2]}")
    if not mask.any():
        raise VortxError("the mask selects no pixel: nothing to compare")
    return a, b, mask


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """Peak signal-to-noise ratio (dB) of uint8 RGB images a, b (h, w, 3) over the pixels where mask
    (h, w) is set: 10 log10(255^2 / MSE), the MSE over those pixels' three channels; inf if equal."""
    a, b, mask = _checked(a, b, mask)
    mse = float(np.mean((a[mask].astype(np.float64) - b[mask].astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(PEAK ** 2 / mse))


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """Mean structural similarity of uint8 RGB images a, b (h, w, 3) over the pixels where mask is set.

    skimage's SSIM map (7 x 7 uniform window, data range 255, per channel) averaged over the masked
    pixels and the channels. Windows at the mask's rim reach outside it: there b takes a's pixels, so
    only the masked pixels' differences count and what lies outside (a render's empty background)
    cannot lower the score.
    """
    from skimage.metrics import structural_similarity  # defers skimage (scikit-image): slow to import

    a, b, mask = _checked(a, b, mask)
    b = np.where(mask[..., None], b, a)
    _, full = structural_similarity(a.astype(np.float64), b.astype(np.float64), data_range=PEAK, channel_axis=2,
                                    full=True)
    return float(full[mask].mean())
