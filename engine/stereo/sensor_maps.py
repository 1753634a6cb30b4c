"""Depth maps from a phone's depth sensor (LiDAR), in place of stereo for the keyframes that have one.

A keyframe with sensor depth gets its map from the sensor alone, at the stereo maps' size: depth
where ARKit's confidence is high (fusion confidence 1) or medium (MEDIUM_WEIGHT), nothing where it
is low or the sensor had no return, and surface normals from the depth. Stereo runs only for the
keyframes without one.

Why not both: a stereo depth on a surface the sensor measured only pulls the fused surface off it.
Measured on the 3D Scanner App corridor (plain white walls, a glossy floor; 73 photos in, the 73
others' LiDAR held out, Finish Off, the whole corridor): 0.47 of the held-out confident LiDAR pixels
within 5 cm of the result with stereo kept wherever the sensor was not confident, 0.63 with stereo
kept only where the sensor had no return or agreed, 0.79 with the sensor alone (median error 5.4,
3.5, 2.4 cm), and the sensor alone skips PatchMatch's minutes. What a phone LiDAR misses (beyond
about 5 m, glass, thin things) is seen up close from other photos of a walk, or stays open.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..capture.images import resized_size
from ..capture.model import Frame, SensorDepth
from ..capture.sensor_depth import HIGH_CONFIDENCE, MEDIUM_CONFIDENCE, read_sensor_depth
from ..geometry.cameras import scale_intrinsics
from ..geometry.depth_normals import depth_normals
from .depth_maps import DepthMap

# Fusion confidence of a medium sensor depth (a high one counts 1). Without a confidence map (an app
# that exports none) every sensor depth counts as medium.
MEDIUM_WEIGHT = 0.5
# How far off its depth a surface may lie and still be what the sensor saw (metres, share of the
# depth), for the finishing's votes: the corridor's LiDAR agrees with itself within 1 cm (median)
# between neighbouring frames; ARKit's drift across a walk adds a few cm. Stereo's margin (8 cm +
# 3 %) would call a door 5 cm behind its wall "on" the wall.
SENSOR_AGREEMENT = (0.02, 0.01)


def sensor_at_size(sensor: SensorDepth, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(depth (h, w) float32 metres, 0 where not trusted; weight (h, w) float32: 1 high, MEDIUM_WEIGHT
    medium, 0 low or no return) of `sensor` resampled to `size` = (w, h), nearest neighbour so no
    depth is blended across an edge."""
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
    return np.where(weight > 0, depth, 0.0).astype(np.float32), weight


def sensor_depth_map(keyframe: int, frame: Frame, long_side: int, with_normals: bool) -> DepthMap:
    """The DepthMap of `frame` (keyframe index `keyframe`) from its sensor alone, at the stereo size
    (long side `long_side`, as `depth_maps.grey_image` sizes a photo); normals from the depth when
    `with_normals` (the other maps carry PatchMatch's)."""
    assert frame.sensor_depth is not None and frame.K is not None and frame.pose is not None
    size = resized_size(frame.width, frame.height, min(long_side, max(frame.width, frame.height)), multiple=1)
    K = scale_intrinsics(frame.K, (frame.width, frame.height), size)
    depth, weight = sensor_at_size(frame.sensor_depth, size)
    normal = None
    if with_normals:
        normals, ok = depth_normals(depth, K)
        normal = np.where(ok[..., None], normals, 0.0).astype(np.float32)
    valid = depth[depth > 0]
    return DepthMap(frame=keyframe, depth=depth, confidence=weight, K=np.asarray(K, np.float64),
                    pose=np.asarray(frame.pose, np.float64), sources=np.zeros(0, np.int64),
                    depth_range=(float(valid.min()), float(valid.max())) if valid.size else (0.0, 0.0), normal=normal,
                    agreement=SENSOR_AGREEMENT)
