"""SfM sanity checks (platform-notes section 1 thresholds) and the lens-distortion measure."""

from __future__ import annotations

import numpy as np
import pytest

from engine.poses.quality import quality_warnings, radial_corner_shift, significant_distortion


def test_a_good_result_has_no_warnings():
    assert quality_warnings(50, [], [50], 0.5, 9000) == []


def test_each_problem_gets_its_own_warning():
    unregistered = [f"{i}.jpg" for i in range(25)]
    warnings = quality_warnings(50, unregistered, [25, 15, 10], 2.0, 80)
    assert len(warnings) == 4
    few, groups, error, points = warnings
    assert "only 25 of 50" in few and "0.jpg" in few and "and 5 more" in few  # long lists are cut
    assert "3 separate groups (25, 15, 10 photos)" in groups
    assert "2.00 px" in error and "80 3D points" in points


def test_sixty_percent_registered_is_still_fine():
    assert quality_warnings(10, ["a.jpg", "b.jpg", "c.jpg", "d.jpg"], [6], 0.5, 500) == []


def test_radial_corner_shift_matches_the_model():
    K = np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]])
    # Farthest corner at r = 0.5 * sqrt(2); the k1 term moves it by f * k1 * r^3.
    assert radial_corner_shift(K, [0.1], 100, 100) == pytest.approx(100 * 0.1 * 0.5**1.5)
    assert radial_corner_shift(K, [0.1, -0.2], 100, 100) == pytest.approx(100 * abs(0.1 * 0.5 - 0.2 * 0.25) * 0.5**0.5)
    assert significant_distortion(6.0, (1080, 1920)) is False  # 0.3 % of the long side
    assert significant_distortion(12.0, (1080, 1920)) is True
