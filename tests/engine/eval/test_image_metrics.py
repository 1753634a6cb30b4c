"""PSNR and SSIM over a mask, against values worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import VortxError
from engine.eval.image_metrics import psnr, ssim

C1, C2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2  # SSIM's stabilisers for data range 255


def test_psnr_counts_only_the_masked_pixels():
    a = np.full((10, 12, 3), 100, np.uint8)
    b = a.copy()
    b[:5] += 10  # masked part: every channel off by 10 -> MSE 100
    b[5:] = 0  # outside the mask: ignored
    mask = np.zeros((10, 12), bool)
    mask[:5] = True
    assert psnr(a, b, mask) == pytest.approx(10 * np.log10(255**2 / 100))
    b[:5, :, 1] = 100  # now only two channels differ: MSE 200 / 3
    assert psnr(a, b, mask) == pytest.approx(10 * np.log10(255**2 / (200 / 3)))
    assert psnr(a, a, mask) == float("inf")


def test_ssim_of_flat_images_is_the_luminance_term():
    a = np.full((20, 20, 3), 100, np.uint8)
    b = np.full((20, 20, 3), 120, np.uint8)
    mask = np.ones((20, 20), bool)
    # No variance: contrast-structure term (0 + C2) / (0 + C2) = 1, luminance term as below.
    expected = (2 * 100 * 120 + C1) / (100**2 + 120**2 + C1)
    assert ssim(a, b, mask) == pytest.approx(expected, rel=1e-6)
    assert ssim(a, a, mask) == pytest.approx(1.0)


def test_ssim_ignores_what_lies_outside_the_mask():
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, (40, 40, 3), dtype=np.uint8)
    b = np.clip(a.astype(int) + rng.integers(-20, 21, a.shape), 0, 255).astype(np.uint8)
    mask = np.zeros((40, 40), bool)
    mask[5:30, 8:35] = True
    value = ssim(a, b, mask)
    assert 0.3 < value < 1.0
    other = b.copy()
    other[~mask] = 0  # a render's empty background
    assert ssim(a, other, mask) == pytest.approx(value)
    # With the whole image masked it is the mean of skimage's SSIM map over every pixel (skimage's own
    # mean leaves out a 3-pixel border).
    from skimage.metrics import structural_similarity

    _, full = structural_similarity(a, b, data_range=255, channel_axis=2, full=True)
    assert ssim(a, b, np.ones((40, 40), bool)) == pytest.approx(full.mean(), rel=1e-6)


def test_bad_inputs_say_what_is_wrong():
    a = np.zeros((4, 4, 3), np.uint8)
    with pytest.raises(VortxError, match="selects no pixel"):
        psnr(a, a, np.zeros((4, 4), bool))
    with pytest.raises(VortxError, match="does not match"):
        ssim(a, a, np.ones((3, 4), bool))
    with pytest.raises(VortxError, match="RGB"):
        psnr(a, a[..., :2], np.ones((4, 4), bool))
