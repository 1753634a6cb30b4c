"""Reading a phone's depth maps (`SensorDepth`) as the reconstruction uses them.

Encodings, as the apps write them:
- "png_mm": a 16-bit single-channel PNG in millimetres, 0 = no depth (3D Scanner App, Stray Scanner,
  Polycam); its confidence a uint8 PNG of the same size.
- "r3d": Record3D's `.depth`, an LZFSE-compressed float32 array in metres of the export's depth size
  (NaN or 0 = no depth); its `.conf` an LZFSE-compressed uint8 array.
Confidence is read as ARKit's ARConfidenceLevel: 0 low, 1 medium, 2 high (Polycam stores 0 / 127 / 255,
`SensorDepth.confidence_high` says so).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from ..geometry.cameras import pixels_to_world
from .model import Frame, SensorDepth
from .naming import name_list

ENCODINGS = ("png_mm", "r3d")
HIGH_CONFIDENCE = 2  # ARConfidenceLevel.high
MEDIUM_CONFIDENCE = 1  # ARConfidenceLevel.medium; below it (low) ARKit's depth is a guess, not a measurement
# Phone LiDAR measures to about 5 m; anything beyond is an artefact of the file, not a depth.
MAX_SENSOR_DEPTH_M = 10.0


def read_sensor_depth(sensor: SensorDepth) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(depth (h, w) float32 metres with 0 where there is none, confidence (h, w) uint8 or None).

    Raises CaptureError naming the file when it cannot be decoded or its sizes disagree.
    """
    if sensor.encoding == "png_mm":
        depth = _read_png(sensor.path, np.uint16, "a 16-bit PNG in millimetres").astype(np.float32) / 1000.0
        confidence = (_read_png(sensor.confidence_path, np.uint8, "an 8-bit PNG of per-pixel confidence")
                      if sensor.confidence_path is not None else None)
    elif sensor.encoding == "r3d":
        if sensor.size is None:
            raise ValueError("an r3d depth map needs its size")
        depth = _read_lzfse(sensor.path, np.float32, sensor.size)
        confidence = (_read_lzfse(sensor.confidence_path, np.uint8, sensor.size)
                      if sensor.confidence_path is not None else None)
    else:
        raise ValueError(f"unknown sensor depth encoding {sensor.encoding!r}; known: {', '.join(ENCODINGS)}")
    if confidence is not None and confidence.shape != depth.shape:
        raise CaptureError(f"confidence map {sensor.confidence_path} is {confidence.shape[1]} x {confidence.shape[0]} "
                           f"but its depth map {sensor.path.name} is {depth.shape[1]} x {depth.shape[0]}: re-export "
                           "the capture, or remove both files.")
    if confidence is not None and sensor.confidence_high != HIGH_CONFIDENCE:  # to ARKit's levels: 127 -> 1, 255 -> 2
        confidence = np.round(confidence.astype(np.float32) * HIGH_CONFIDENCE / sensor.confidence_high).astype(np.uint8)
    depth = np.where(np.isfinite(depth) & (depth > 0) & (depth < MAX_SENSOR_DEPTH_M), depth, 0.0).astype(np.float32)
    return depth, confidence


def sensor_measured(depth: np.ndarray, confidence: Optional[np.ndarray]) -> np.ndarray:
    """(h, w) bool: where the sensor measured a depth the reconstruction takes (a return, and confidence
    medium or high when the app exports one), as `read_sensor_depth` returns them."""
    measured = depth > 0
    if confidence is not None:
        measured &= confidence >= MEDIUM_CONFIDENCE
    return measured


def _read_png(path: Path, dtype: type, what: str) -> np.ndarray:
    import cv2  # defers cv2 (OpenCV) off the light paths

    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as error:
        raise CaptureError(f"cannot read depth file {path}: {error.strerror or error}") from error
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None or image.ndim != 2 or image.dtype != dtype:
        raise CaptureError(f"{path} is not {what} (corrupt or another kind of file): re-export the capture, or "
                           "remove the file to use its photo without depth.")
    return image


def _read_lzfse(path: Path, dtype: type, size: tuple[int, int]) -> np.ndarray:
    try:
        import lzfse  # defers lzfse: only Record3D exports need it
    except ImportError as error:  # a pinned dependency; a hand-made environment may lack it
        raise CaptureError("reading Record3D depth needs the lzfse package (pip install lzfse)") from error
    try:
        raw = lzfse.decompress(path.read_bytes())
    except OSError as error:
        raise CaptureError(f"cannot read depth file {path}: {error.strerror or error}") from error
    except Exception as error:  # lzfse raises its own error type for a corrupt stream
        raise CaptureError(f"{path} is not an LZFSE-compressed Record3D depth file ({error}): re-export the "
                           "capture, or remove the file to use its photo without depth.") from error
    width, height = size
    expected = width * height * np.dtype(dtype).itemsize
    if len(raw) != expected:
        raise CaptureError(f"{path} holds {len(raw)} bytes once decompressed, but a {width} x {height} "
                           f"{np.dtype(dtype).name} map needs {expected}: the export's metadata and its depth "
                           "files disagree; re-export it.")
    return np.frombuffer(raw, dtype=dtype).reshape(height, width).copy()


def check_sensor_depths(frames: list[Frame], warnings: list[str]) -> list[Frame]:
    """`frames` with each sensor depth that cannot be read removed (the photo stays); one warning in
    `warnings` names those files and why."""
    broken: list[str] = []
    kept = []
    for frame in frames:
        if frame.sensor_depth is not None:
            try:
                read_sensor_depth(frame.sensor_depth)
            except CaptureError:
                broken.append(frame.sensor_depth.path.name)
                frame = replace(frame, sensor_depth=None)
        kept.append(frame)
    if broken:
        warnings.append(f"{len(broken)} depth map(s) are corrupt or of another kind, their photos are used without "
                        f"depth: {name_list(broken)} (re-export the capture to keep their depth)")
    return kept


POINT_STRIDE = 8  # every 8th depth pixel each way: 768 points from a 256 x 192 map
MAX_SENSOR_POINTS = 200_000


def sensor_points(frames: list[Frame]) -> tuple[np.ndarray, np.ndarray]:
    """(points (N, 3) float64 world, colours (N, 3) uint8 RGB) from the frames' confident sensor depth,
    every POINT_STRIDE-th pixel, at most MAX_SENSOR_POINTS (evenly thinned): the capture's point cloud,
    as SfM's sparse points are for photos alone. Frames whose depth or photo cannot be read add none."""
    import cv2  # defers cv2 (OpenCV) off the light paths

    posed = [f for f in frames if f.sensor_depth is not None and f.pose is not None and f.K is not None]
    points, colours = [], []
    for frame in posed:
        try:
            depth, confidence = read_sensor_depth(frame.sensor_depth)
        except CaptureError:
            continue
        h, w = depth.shape
        keep = depth > 0
        if confidence is not None:
            keep &= confidence >= HIGH_CONFIDENCE
        grid = np.zeros_like(keep)
        grid[POINT_STRIDE // 2::POINT_STRIDE, POINT_STRIDE // 2::POINT_STRIDE] = True
        v, u = np.nonzero(keep & grid)
        if len(v) == 0:
            continue
        sx, sy = w / frame.width, h / frame.height  # the depth map is the photo at another size
        K = frame.K * np.array([[sx], [sy], [1.0]])
        points.append(pixels_to_world(u, v, depth[v, u], K, frame.pose))
        # Colours from an eighth-size decode of the photo: a point needs one pixel, not 1920 x 1440.
        bgr = cv2.imread(str(frame.image_path), cv2.IMREAD_REDUCED_COLOR_8)
        if bgr is None:
            colours.append(np.full((len(v), 3), 128, np.uint8))
            continue
        ph, pw = bgr.shape[:2]
        cols = np.clip(((u + 0.5) / w * pw).astype(int), 0, pw - 1)
        rows = np.clip(((v + 0.5) / h * ph).astype(int), 0, ph - 1)
        colours.append(bgr[rows, cols, ::-1])
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    all_points, all_colours = np.concatenate(points), np.concatenate(colours).astype(np.uint8)
    if len(all_points) > MAX_SENSOR_POINTS:
        chosen = np.linspace(0, len(all_points) - 1, MAX_SENSOR_POINTS).astype(np.int64)
        all_points, all_colours = all_points[chosen], all_colours[chosen]
    return all_points, all_colours
