"""A phone's depth sensor (LiDAR) merged into the stereo depth maps, pixel by pixel.

Trust follows ARKit's confidence: where the sensor is confident (high) its depth replaces stereo's,
with full confidence and its own surface normals, because a phone LiDAR is within about 1 cm up to
4-5 m on plain walls and glossy floors where stereo has no texture to match. Where it is medium it
fills pixels stereo left empty, at half confidence; where it is low or has no return (beyond about
5 m, thin things, dark or glassy surfaces) stereo's depth stays. So the fused TSDF weighs each
depth by the source that is trusted there (`depth_filters.observation_weights` multiplies by it).

Keyframes that got no stereo map (more keyframes than `max_references`) still get a map from the
sensor alone: its depth costs nothing to compute, so every photo with depth adds its view.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..capture.model import Frame, SensorDepth
from ..capture.sensor_depth import HIGH_CONFIDENCE, read_sensor_depth
from ..geometry.cameras import scale_intrinsics
from ..geometry.depth_normals import depth_normals
from .depth_maps import DepthMap

MEDIUM_CONFIDENCE = 1  # ARConfidenceLevel.medium
MEDIUM_WEIGHT = 0.5  # fusion confidence of a medium sensor depth (a high one counts 1, as a perfect stereo match)
# Without a confidence map (an app that does not export one) every sensor depth counts as medium.


@dataclass
class SensorMergeCount:
    """Pixels of the merged maps by where their depth came from, for the run's report."""

    sensor: int = 0  # sensor depth (high confidence, or medium where stereo had none)
    stereo: int = 0  # stereo depth kept
    empty: int = 0  # neither

    def add(self, source: np.ndarray) -> None:
        self.sensor += int((source == 1).sum())
        self.stereo += int((source == 2).sum())
        self.empty += int((source == 0).sum())

    def summary(self) -> dict[str, float]:
        total = max(1, self.sensor + self.stereo + self.empty)
        return {"sensor_share": round(self.sensor / total, 4), "stereo_share": round(self.stereo / total, 4),
                "empty_share": round(self.empty / total, 4)}


def sensor_at_size(sensor: SensorDepth, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(depth (h, w) float32 metres, weight (h, w) float32: 1 high, MEDIUM_WEIGHT medium, 0 low or none)
    of `sensor` resampled to `size` = (w, h), nearest neighbour so no depth is blended across an edge."""
    depth, confidence = read_sensor_depth(sensor)
    if confidence is None:
        weight = np.where(depth > 0, MEDIUM_WEIGHT, 0.0).astype(np.float32)
    else:
        weight = np.select([confidence >= HIGH_CONFIDENCE, confidence == MEDIUM_CONFIDENCE], [1.0, MEDIUM_WEIGHT],
                           0.0).astype(np.float32)
        weight[depth <= 0] = 0.0
    if depth.shape[::-1] != tuple(size):
        depth = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
        weight = cv2.resize(weight, size, interpolation=cv2.INTER_NEAREST)
    return depth, weight


def merge_sensor_depth(stereo: DepthMap, sensor: SensorDepth) -> tuple[DepthMap, np.ndarray]:
    """`stereo` with `sensor`'s depth where it is trusted (module doc), and the (h, w) uint8 source of
    each pixel: 1 sensor, 2 stereo, 0 none. Normals of sensor pixels come from the sensor's depth."""
    h, w = stereo.depth.shape
    depth, weight = sensor_at_size(sensor, (w, h))
    has_stereo = stereo.depth > 0
    take = (weight >= 1.0) | ((weight > 0) & ~has_stereo)
    merged_depth = np.where(take, depth, stereo.depth).astype(np.float32)
    merged_confidence = np.where(take, weight, stereo.confidence).astype(np.float32)
    sensor_normals, sensor_ok = depth_normals(np.where(take, depth, 0.0), stereo.K)
    if stereo.normal is not None:
        normal = np.where((take & sensor_ok)[..., None], sensor_normals, stereo.normal).astype(np.float32)
        normal[take & ~sensor_ok] = 0.0  # no plane known there: observation_weights then uses its default angle
    else:
        normal = None
    source = np.where(take, 1, np.where(has_stereo, 2, 0)).astype(np.uint8)
    return replace(stereo, depth=merged_depth, confidence=merged_confidence, normal=normal), source


def sensor_only_map(frame_index: int, sensor: SensorDepth, K: np.ndarray, pose: np.ndarray,
                    size: tuple[int, int], with_normals: bool) -> DepthMap:
    """A DepthMap of keyframe `frame_index` from its sensor alone, at `size` = (w, h) with K (3, 3)
    already in pixels of that size; normals from the depth when the other maps carry normals."""
    depth, weight = sensor_at_size(sensor, size)
    depth = np.where(weight > 0, depth, 0.0).astype(np.float32)
    normal = None
    if with_normals:
        normals, ok = depth_normals(depth, K)
        normal = np.where(ok[..., None], normals, 0.0).astype(np.float32)
    return DepthMap(frame=frame_index, depth=depth, confidence=weight, K=np.asarray(K, np.float64),
                    pose=np.asarray(pose, np.float64), sources=np.zeros(0, np.int64), depth_range=(0.0, 0.0),
                    normal=normal)


def merge_sensor_maps(maps: list[DepthMap], keyframes: list[Frame], counts: SensorMergeCount) -> list[DepthMap]:
    """The stereo `maps` (DepthMap.frame indexing `keyframes`) with each keyframe's sensor depth merged
    in, plus a sensor-only map for every keyframe with sensor depth but no stereo map, at the stereo
    maps' size. `counts` receives where the merged pixels came from."""
    if not maps:
        return maps
    height, width = maps[0].depth.shape
    with_normals = maps[0].normal is not None
    merged: list[DepthMap] = []
    for m in maps:
        sensor = keyframes[m.frame].sensor_depth
        if sensor is not None:
            m, source = merge_sensor_depth(m, sensor)
            counts.add(source)
        merged.append(m)
    covered = {m.frame for m in maps}
    for k, frame in enumerate(keyframes):
        if k in covered or frame.sensor_depth is None or frame.K is None or frame.pose is None:
            continue
        K = scale_intrinsics(frame.K, (frame.width, frame.height), (width, height))
        extra = sensor_only_map(k, frame.sensor_depth, K, frame.pose, (width, height), with_normals)
        counts.add(np.where(extra.depth > 0, 1, 0))
        merged.append(extra)
    return merged
