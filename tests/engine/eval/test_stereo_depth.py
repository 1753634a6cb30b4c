"""engine eval-depth's numbers against hand-made depth maps with known errors."""

from __future__ import annotations

import numpy as np

from engine.eval.stereo_depth import compare_depth

K = np.array([[80.0, 0, 40.0], [0, 80.0, 30.0], [0, 0, 1]])


def test_a_depth_map_three_percent_too_far_is_within_five_percent_everywhere() -> None:
    true = np.full((60, 80), 2.0, np.float32)
    pred = true * 1.03
    scores = compare_depth(pred, np.full_like(pred, 0.8), true, K)
    assert np.isclose(scores["median_rel"], 0.03, atol=1e-6)
    assert scores["within_5pct"] == 1.0 and scores["complete"] == 1.0
    assert scores["normals_30deg"] == 1.0, "a scaled plane keeps its normal"


def test_completeness_errors_normals_and_confidence_calibration() -> None:
    rng = np.random.default_rng(0)
    true = np.full((60, 80), 2.0, np.float32)
    pred = true.copy()
    pred[:, :40] *= 1.0 + rng.normal(0, 0.3, (60, 40)).astype(np.float32)  # left half: wild errors, rough normals
    pred[:30, 40:] = 0.0  # a quarter without stereo depth
    confidence = np.where(np.arange(80)[None, :] < 40, rng.uniform(0.2, 0.4, (60, 80)),
                          rng.uniform(0.8, 1.0, (60, 80))).astype(np.float32)
    scores = compare_depth(pred, confidence, true, K)
    has = pred > 0  # the noise pushes a few left-half depths below zero: no depth there either
    assert np.isclose(scores["complete"], has.mean()) and 0.74 < scores["complete"] <= 0.75
    left = (np.abs(pred[:, :40] - 2.0) / 2.0)[has[:, :40]]
    assert np.isclose(scores["within_5pct"], (np.sum(left < 0.05) + 30 * 40) / has.sum())
    assert 0.3 < scores["normals_30deg"] < 0.8
    assert scores["confidence_spearman"] < -0.5, "the confident half is the accurate one"
    assert scores["confidence_quartiles"][-1] < scores["confidence_quartiles"][0]


def test_a_map_scaled_by_its_poses_is_right_after_its_own_scale_is_taken_out() -> None:
    rng = np.random.default_rng(1)
    true = rng.uniform(1.0, 3.0, (60, 80)).astype(np.float32)
    pred = true * 1.12  # a pose scale 12 % off moves every depth 12 %
    pred[:, :20] = true[:, :20] * 1.40  # a quarter of the map wrong beyond any scale
    scores = compare_depth(pred, np.full_like(pred, 0.8), true, K)
    assert scores["within_5pct"] == 0.0
    assert np.isclose(scores["scale"], 1.12, atol=1e-3)
    assert np.isclose(scores["within_5pct_scaled"], 0.75, atol=1e-6)
