"""Depth maps from a phone's LiDAR in place of stereo: confidence kept as fusion weight, resampled
without blending, and only the keyframes without sensor depth matched by stereo."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.capture.model import Frame, SensorDepth
from engine.stereo.depth_filters import observation_weights
from engine.stereo.sensor_maps import MEDIUM_WEIGHT, sensor_depth_map

SW, SH = 8, 6  # sensor
PW, PH = 64, 48  # photo; the stereo maps are 16 x 12 at long side 16
K_PHOTO = np.array([[56.0, 0.0, 32.0], [0.0, 56.0, 24.0], [0.0, 0.0, 1.0]])


def write_sensor(folder: Path, depth_m: np.ndarray, confidence: np.ndarray | None, name: str = "d") -> SensorDepth:
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / f"{name}.png"), np.round(depth_m * 1000).astype(np.uint16))
    conf_path = None
    if confidence is not None:
        conf_path = folder / f"{name}_conf.png"
        cv2.imwrite(str(conf_path), confidence.astype(np.uint8))
    return SensorDepth(folder / f"{name}.png", "png_mm", conf_path)


def frame_with(sensor: SensorDepth) -> Frame:
    return Frame(Path("p.jpg"), PW, PH, K_PHOTO, np.eye(4), sensor_depth=sensor)


def test_confidence_becomes_fusion_weight_and_low_is_dropped(tmp_path):
    # Columns 0-1 high, 2-3 medium, 4-5 low, 6-7 no return; a plane leaning from 2.0 to 2.7 m.
    depth = np.tile(2.0 + 0.1 * np.arange(SW), (SH, 1))
    depth[:, 6:] = 0.0
    confidence = np.tile(np.array([2, 2, 1, 1, 0, 0, 0, 0]), (SH, 1))
    m = sensor_depth_map(3, frame_with(write_sensor(tmp_path, depth, confidence)), long_side=16, with_normals=True)

    assert m.frame == 3 and m.depth.shape == (12, 16) and len(m.sources) == 0
    expected = np.repeat(depth, 2, axis=1).repeat(2, axis=0)  # nearest: map column c shows sensor column c // 2
    np.testing.assert_allclose(m.depth[:, :8], expected[:, :8], rtol=1e-6)
    np.testing.assert_allclose(m.confidence[:, :4], 1.0)
    np.testing.assert_allclose(m.confidence[:, 4:8], MEDIUM_WEIGHT)
    assert (m.depth[:, 8:] == 0).all() and (m.confidence[:, 8:] == 0).all()  # low and none: no depth
    np.testing.assert_allclose(m.K, K_PHOTO * np.array([[0.25], [0.25], [1.0]]))  # the photo's K at the map size
    assert m.depth_range == pytest.approx((2.0, 2.3))


def test_sensor_pixels_carry_the_sensor_surface_normal(tmp_path):
    """A floor-like plane leaning away (depth grows with the row): its normal tilts towards the rows,
    and fusion weighs every depth by it."""
    depth = np.tile(2.0 + 0.3 * np.arange(SH)[:, None], (1, SW)).astype(np.float64)
    m = sensor_depth_map(0, frame_with(write_sensor(tmp_path, depth, np.full((SH, SW), 2))), 16, with_normals=True)
    inner = m.normal[3:-3, 3:-3].reshape(-1, 3)
    assert np.all(np.abs(inner[:, 0]) < 1e-6) and np.all(np.abs(inner[:, 1]) > 0.3)
    weights = observation_weights(m.depth, m.confidence, m.K, m.normal)
    assert np.all(weights[m.depth > 0] > 0)
    assert sensor_depth_map(0, frame_with(write_sensor(tmp_path, depth, None, "n")), 16, with_normals=False).normal is None


def test_without_a_confidence_map_every_depth_counts_as_medium(tmp_path):
    m = sensor_depth_map(0, frame_with(write_sensor(tmp_path, np.full((SH, SW), 1.5), None)), 16, with_normals=False)
    np.testing.assert_allclose(m.depth, 1.5)
    np.testing.assert_allclose(m.confidence, MEDIUM_WEIGHT)
