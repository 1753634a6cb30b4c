"""A phone's LiDAR merged into stereo depth maps: sensor where confident, stereo where it is not."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from engine.capture.model import Frame, SensorDepth
from engine.stereo.depth_maps import DepthMap
from engine.stereo.sensor_merge import MEDIUM_WEIGHT, SensorMergeCount, merge_sensor_depth, merge_sensor_maps
from engine.stereo.depth_filters import observation_weights

SW, SH = 8, 6  # sensor
MW, MH = 16, 12  # stereo map: twice the sensor's size
K_MAP = np.array([[14.0, 0.0, 8.0], [0.0, 14.0, 6.0], [0.0, 0.0, 1.0]])


def write_sensor(folder: Path, depth_m: np.ndarray, confidence: np.ndarray | None, name: str = "d") -> SensorDepth:
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / f"{name}.png"), np.round(depth_m * 1000).astype(np.uint16))
    conf_path = None
    if confidence is not None:
        conf_path = folder / f"{name}_conf.png"
        cv2.imwrite(str(conf_path), confidence.astype(np.uint8))
    return SensorDepth(folder / f"{name}.png", "png_mm", conf_path)


def stereo_map(depth: np.ndarray, confidence: float = 0.6, frame: int = 0) -> DepthMap:
    normal = np.zeros((MH, MW, 3), np.float32)
    normal[..., 2] = -1.0
    return DepthMap(frame=frame, depth=depth.astype(np.float32),
                    confidence=np.where(depth > 0, confidence, 0.0).astype(np.float32), K=K_MAP, pose=np.eye(4),
                    sources=np.array([1, 2]), depth_range=(0.5, 5.0), normal=np.where(depth[..., None] > 0, normal, 0))


def test_each_pixel_takes_the_source_trusted_there(tmp_path):
    # Sensor columns 0-1 high confidence, 2-3 medium, 4-5 low, 6-7 no return; a tilted plane 2.0-2.7 m.
    sensor_depth = np.tile(2.0 + 0.1 * np.arange(SW), (SH, 1))
    sensor_depth[:, 6:] = 0.0
    confidence = np.tile(np.array([2, 2, 1, 1, 0, 0, 0, 0]), (SH, 1))
    sensor = write_sensor(tmp_path, sensor_depth, confidence)
    stereo_depth = np.full((MH, MW), 3.0)
    stereo_depth[: MH // 2] = 0.0  # stereo found nothing in the top half

    merged, source = merge_sensor_depth(stereo_map(stereo_depth), sensor)

    # Nearest-neighbour upsampling: map column c shows sensor column c // 2.
    expected_sensor = np.repeat(sensor_depth, 2, axis=1).repeat(2, axis=0)
    high = np.zeros((MH, MW), bool)
    high[:, :4] = True
    medium = np.zeros((MH, MW), bool)
    medium[:, 4:8] = True
    top = np.zeros((MH, MW), bool)
    top[: MH // 2] = True
    np.testing.assert_allclose(merged.depth[high], expected_sensor[high], rtol=1e-6)  # high: sensor always
    np.testing.assert_allclose(merged.confidence[high], 1.0)
    np.testing.assert_allclose(merged.depth[medium & top], expected_sensor[medium & top], rtol=1e-6)  # fills gaps
    np.testing.assert_allclose(merged.confidence[medium & top], MEDIUM_WEIGHT)
    np.testing.assert_allclose(merged.depth[medium & ~top], 3.0)  # medium never overrides stereo
    np.testing.assert_allclose(merged.depth[:, 8:][~top[:, 8:]], 3.0)  # low / none: stereo stays
    assert (merged.depth[:, 8:][top[:, 8:]] == 0).all()  # neither: still empty
    assert (source[high] == 1).all() and (source[:, 8:][top[:, 8:]] == 0).all() and (source[medium & ~top] == 2).all()


def test_sensor_pixels_get_the_sensor_surface_normal(tmp_path):
    """A floor-like plane leaning away (depth grows with the row): its normal is not the stereo map's
    fronto-parallel one, and fusion weighs it by its own viewing angle."""
    v = np.arange(SH)[:, None]
    sensor_depth = np.tile(2.0 + 0.3 * v, (1, SW)).astype(np.float64)
    sensor = write_sensor(tmp_path, sensor_depth, np.full((SH, SW), 2))
    merged, _ = merge_sensor_depth(stereo_map(np.full((MH, MW), 2.5)), sensor)
    inner = merged.normal[3:-3, 3:-3].reshape(-1, 3)
    assert np.all(np.abs(inner[:, 0]) < 1e-6)  # no tilt sideways
    assert np.all(np.abs(inner[:, 1]) > 0.3)  # tilted towards the rows, unlike the stereo normal (0, 0, -1)
    weights = observation_weights(merged.depth, merged.confidence, merged.K, merged.normal)
    assert np.all(weights[merged.depth > 0] > 0)


def test_without_a_confidence_map_the_sensor_only_fills_gaps(tmp_path):
    sensor = write_sensor(tmp_path, np.full((SH, SW), 1.5), None)
    stereo_depth = np.full((MH, MW), 2.0)
    stereo_depth[:, :MW // 2] = 0
    merged, _ = merge_sensor_depth(stereo_map(stereo_depth), sensor)
    np.testing.assert_allclose(merged.depth[:, :MW // 2], 1.5)
    np.testing.assert_allclose(merged.depth[:, MW // 2:], 2.0)


def test_keyframes_without_a_stereo_map_get_one_from_the_sensor(tmp_path):
    sensors = [write_sensor(tmp_path, np.full((SH, SW), 1.0 + i), np.full((SH, SW), 2), name=f"d{i}") for i in range(3)]
    K_photo = K_MAP * np.array([[4.0], [4.0], [1.0]])  # photos 64 x 48, four times the map
    frames = [Frame(Path(f"p{i}.jpg"), 64, 48, K_photo, np.eye(4), sensor_depth=s) for i, s in enumerate(sensors)]
    frames.append(Frame(Path("p3.jpg"), 64, 48, K_photo, np.eye(4)))  # no sensor: no extra map
    counts = SensorMergeCount()
    maps = merge_sensor_maps([stereo_map(np.full((MH, MW), 9.0), frame=1)], frames, counts)

    assert sorted(m.frame for m in maps) == [0, 1, 2]
    by_frame = {m.frame: m for m in maps}
    np.testing.assert_allclose(by_frame[1].depth, 2.0)  # merged: high confidence everywhere
    np.testing.assert_allclose(by_frame[0].depth, 1.0)
    np.testing.assert_allclose(by_frame[2].K, K_MAP)  # the photo's K scaled to the map size
    assert by_frame[2].depth.shape == (MH, MW) and by_frame[2].normal is not None
    assert counts.summary()["sensor_share"] == 1.0
