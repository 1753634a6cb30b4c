"""Reading a phone's depth maps (`SensorDepth`) as the reconstruction uses them.

Encodings, as the apps write them:
- "png_mm": a 16-bit single-channel PNG in millimetres, 0 = no depth (3D Scanner App, Stray Scanner,
  Polycam); its confidence a uint8 PNG of the same size.
- "r3d": Record3D's `.depth`, an LZFSE-compressed float32 array in metres of the export's depth size
  (NaN or 0 = no depth); its `.conf` an LZFSE-compressed uint8 array.
Confidence follows ARKit's ARConfidenceLevel: 0 low, 1 medium, 2 high.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from .model import Frame, SensorDepth
from .naming import name_list

ENCODINGS = ("png_mm", "r3d")
HIGH_CONFIDENCE = 2  # ARConfidenceLevel.high
# Phone LiDAR measures to about 5 m; anything beyond is an artefact of the file, not a depth.
MAX_SENSOR_DEPTH_M = 10.0


def read_sensor_depth(sensor: SensorDepth) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(depth (h, w) float32 metres with 0 where there is none, confidence (h, w) uint8 or None).

    Raises CaptureError naming the file when it cannot be decoded or its sizes disagree.
    """
    if sensor.encoding == "png_mm":
        depth = _read_png(sensor.path, np.uint16, "a 16-bit PNG in millimetres").astype(np.float32) / 1000.0
        confidence = (_read_png(sensor.confidence_path, np.uint8, "an 8-bit PNG of ARKit confidence (0, 1, 2)")
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
    depth = np.where(np.isfinite(depth) & (depth > 0) & (depth < MAX_SENSOR_DEPTH_M), depth, 0.0).astype(np.float32)
    return depth, confidence


def _read_png(path: Path, dtype: type, what: str) -> np.ndarray:
    import cv2  # deferred: the light paths do not need OpenCV

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
        import liblzfse
    except ImportError as error:  # pragma: no cover - a pinned dependency
        raise CaptureError("reading Record3D depth needs the pyliblzfse package (pip install pyliblzfse)") from error
    try:
        raw = liblzfse.decompress(path.read_bytes())
    except OSError as error:
        raise CaptureError(f"cannot read depth file {path}: {error.strerror or error}") from error
    except Exception as error:  # liblzfse raises its own error type for a corrupt stream
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
            except CaptureError as error:
                broken.append(f"{frame.sensor_depth.path.name} ({str(error).split(':')[0]})")
                frame = replace(frame, sensor_depth=None)
        kept.append(frame)
    if broken:
        warnings.append(f"{len(broken)} depth map(s) could not be read, their photos are used without depth: "
                        f"{name_list(broken)}")
    return kept
