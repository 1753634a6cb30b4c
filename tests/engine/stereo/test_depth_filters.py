"""Cleaning a stereo depth map before fusion, and the weight of each depth in fusion."""

from __future__ import annotations

import numpy as np

from engine.stereo.depth_filters import median_depth, observation_weights, remove_speckles

K = np.array([[100.0, 0, 50.0], [0, 100.0, 40.0], [0, 0, 1]])


def test_small_islands_of_depth_are_speckles_and_large_regions_are_not() -> None:
    depth = np.full((80, 100), 2.0, np.float32)
    depth[10:13, 10:13] = 3.0  # a 9-pixel island at another depth: matching noise
    depth[40:70, 50:90] = 1.0  # a large region at another depth: a real object
    drop = remove_speckles(depth, share=0.002)  # speckles are regions under 16 pixels
    assert drop[10:13, 10:13].all()
    assert not drop[40:70, 50:90].any()
    assert not drop[30, 30], "the background plane is one large region"
    assert not remove_speckles(np.zeros((10, 10), np.float32)).any()


def test_the_median_takes_jitter_out_of_a_plane_but_keeps_edges_and_holes() -> None:
    rng = np.random.default_rng(0)
    depth = (2.0 + rng.normal(0, 0.01, (60, 80))).astype(np.float32)
    depth[:, 40:] = (1.0 + rng.normal(0, 0.005, (60, 40))).astype(np.float32)  # a step edge at column 40
    depth[20:25, 10:15] = 0.0  # a hole
    smooth = median_depth(depth)
    plane = np.zeros_like(depth, bool)
    plane[5:55, 5:35] = True
    plane &= depth > 0
    assert np.std(smooth[plane] - 2.0) < 0.6 * np.std(depth[plane] - 2.0)
    assert (smooth[20:25, 10:15] == 0).all(), "holes are never filled"
    assert np.all(np.abs(smooth[:, 38:40] - 2.0) < 0.05) and np.all(np.abs(smooth[:, 40:42] - 1.0) < 0.05), \
        "no depth moves across the edge"


def test_weights_favour_confident_frontal_near_depths() -> None:
    frontal = np.full((40, 60), 1.0, np.float32)
    v = np.arange(40, dtype=np.float32)[:, None]
    slanted = np.broadcast_to(1.0 / (0.2 + 0.02 * v), (40, 60)).astype(np.float32)  # a floor-like slope
    confidence = np.full((40, 60), 0.9, np.float32)
    w_frontal = observation_weights(frontal, confidence, K)[20, 30]
    w_far = observation_weights(2 * frontal, confidence, K)[20, 30]
    w_unsure = observation_weights(frontal, 0.5 * confidence, K)[20, 30]
    w_slanted = observation_weights(slanted, confidence, K)[20, 30] * (slanted[20, 30] ** 2)  # same depth factor
    assert np.isclose(w_far, w_frontal / 4, rtol=1e-3), "the expected error grows with depth squared"
    assert np.isclose(w_unsure, w_frontal / 2, rtol=1e-3)
    assert w_slanted < 0.8 * w_frontal, "a surface seen at a slant weighs less"
    assert observation_weights(np.zeros((5, 5), np.float32), np.zeros((5, 5), np.float32), K).max() == 0
