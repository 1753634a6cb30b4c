"""Readers for COLMAP sparse models, text (cameras.txt, images.txt) and binary (.bin).

Written here rather than through `pycolmap.Reconstruction(path)` because the loader needs only
cameras, image poses and the sparse points' positions and colours (a model without points3D.* still
loads: the points are optional), it must
report an unsupported camera model by name instead of failing inside C++, and `python -m engine
info` should not pay for importing pycolmap. Layouts follow COLMAP's `read_write_model.py`; the
files written by COLMAP 4.2 (pycolmap 4.2.1), whose rigs/frames files are ignored here, have
the same cameras/images layout (checked by tests).

Binary layouts (little endian):
  cameras.bin: uint64 n, then n x [uint32 camera_id, int32 model_id, uint64 width, uint64 height,
               float64 params[num_params(model)]]
  images.bin:  uint64 n, then n x [uint32 image_id, float64 qw qx qy qz, float64 tx ty tz,
               uint32 camera_id, name (bytes up to NUL), uint64 num_points2D,
               num_points2D x (float64 x, float64 y, int64 point3D_id)]
  points3D.bin: uint64 n, then n x [uint64 point3D_id, float64 x y z, uint8 r g b, float64 error,
               uint64 track_length, track_length x (int32 image_id, int32 point2D_idx)]
Text: points3D.txt has one line per point: POINT3D_ID X Y Z R G B ERROR then the track.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import CaptureError

# model id -> (name, number of parameters), COLMAP src/colmap/sensor/models.h.
CAMERA_MODELS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
    4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16), 12: ("SIMPLE_DIVISION", 4), 13: ("DIVISION", 5),
    14: ("SIMPLE_FISHEYE", 3), 15: ("FISHEYE", 4), 16: ("EUCM", 6), 17: ("EQUIRECTANGULAR", 2),
}
_PARAMS_BY_NAME = {name: count for name, count in CAMERA_MODELS.values()}


@dataclass(frozen=True)
class ColmapCamera:
    camera_id: int
    model: str
    width: int
    height: int
    params: np.ndarray  # (num_params,) float64 in COLMAP's order for `model`


@dataclass(frozen=True)
class ColmapImage:
    image_id: int
    qvec: np.ndarray  # (4,) world-to-camera rotation as a quaternion (w, x, y, z)
    tvec: np.ndarray  # (3,) world-to-camera translation
    camera_id: int
    name: str  # path relative to the images folder, "/"-separated


@dataclass(frozen=True)
class ColmapModel:
    folder: Path
    kind: str  # "text" or "binary"
    cameras: dict[int, ColmapCamera]
    images: list[ColmapImage]

    @property
    def cameras_file(self) -> Path:
        return self.folder / ("cameras.txt" if self.kind == "text" else "cameras.bin")

    @property
    def images_file(self) -> Path:
        return self.folder / ("images.txt" if self.kind == "text" else "images.bin")


@dataclass(frozen=True)
class ColmapPoints:
    xyz: np.ndarray  # (N, 3) float64, in the model's world
    rgb: np.ndarray  # (N, 3) uint8


def points_file(folder: Path, kind: str) -> Path:
    return folder / ("points3D.txt" if kind == "text" else "points3D.bin")


def read_points(folder: Path, kind: str) -> ColmapPoints | None:
    """The sparse points of the model in `folder` ("text" or "binary"), or None when it has no
    points3D file; CaptureError naming the file when it is unreadable."""
    path = points_file(folder, kind)
    if not path.is_file():
        return None
    return _read_points_text(path) if kind == "text" else _read_points_binary(path)


def model_kind(folder: Path) -> str | None:
    """"binary" or "text" when `folder` holds a COLMAP model (binary wins when both exist, as in
    COLMAP itself), else None."""
    for kind, suffix in (("binary", ".bin"), ("text", ".txt")):
        if (folder / f"cameras{suffix}").is_file() and (folder / f"images{suffix}").is_file():
            return kind
    return None


def read_model(folder: Path) -> ColmapModel:
    """Cameras and registered images of the model in `folder`; CaptureError naming the bad file."""
    kind = model_kind(folder)
    if kind is None:
        raise CaptureError(f"{folder} holds no COLMAP model: expected cameras.txt + images.txt or "
                           "cameras.bin + images.bin.")
    if kind == "text":
        cameras, images = _read_cameras_text(folder / "cameras.txt"), _read_images_text(folder / "images.txt")
    else:
        cameras, images = _read_cameras_binary(folder / "cameras.bin"), _read_images_binary(folder / "images.bin")
    return ColmapModel(folder=folder, kind=kind, cameras=cameras, images=images)


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, stripped text) of every line, comments included: images.txt needs blank lines."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as error:
        raise CaptureError(f"cannot read {path}: {error.strerror or error}.") from error
    return [(number, line.strip()) for number, line in enumerate(text.splitlines(), start=1)]


def _bad_line(path: Path, number: int, why: str) -> CaptureError:
    return CaptureError(f"{path} line {number} is not valid COLMAP text ({why}): re-export the model "
                        "with COLMAP (File > Export model as text).")


def _read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, line in _data_lines(path):
        if not line or line.startswith("#"):
            continue
        fields = line.split()
        try:
            camera_id, model, width, height = int(fields[0]), fields[1], int(fields[2]), int(fields[3])
            params = np.array([float(v) for v in fields[4:]], dtype=np.float64)
        except (IndexError, ValueError) as error:
            raise _bad_line(path, number, str(error)) from error
        expected = _PARAMS_BY_NAME.get(model)
        if expected is not None and params.size != expected:
            raise _bad_line(path, number, f"{model} has {expected} parameters, found {params.size}")
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    return cameras


def _read_images_text(path: Path) -> list[ColmapImage]:
    """Two lines per image; the second (its 2D points) may be empty, so it is consumed unconditionally."""
    images = []
    lines = _data_lines(path)
    index = 0
    while index < len(lines):
        number, line = lines[index]
        index += 1
        if not line or line.startswith("#"):
            continue
        index += 1  # the POINTS2D line
        fields = line.split(maxsplit=9)
        try:
            image_id = int(fields[0])
            qvec = np.array([float(v) for v in fields[1:5]])
            tvec = np.array([float(v) for v in fields[5:8]])
            camera_id, name = int(fields[8]), fields[9]
        except (IndexError, ValueError) as error:
            raise _bad_line(path, number, str(error)) from error
        images.append(ColmapImage(image_id, qvec, tvec, camera_id, name))
    return images


class _Reader:
    """Sequential little-endian reads from a bytes buffer with a clear error on truncation."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as error:
            raise CaptureError(f"cannot read {path}: {error.strerror or error}.") from error
        self.offset = 0

    def take(self, fmt: str) -> tuple:
        size = struct.calcsize(fmt)
        if self.offset + size > len(self.data):
            raise CaptureError(f"{self.path} is truncated or not a COLMAP binary file (ends at byte "
                               f"{len(self.data)}): re-export the model with COLMAP.")
        values = struct.unpack_from(fmt, self.data, self.offset)
        self.offset += size
        return values

    def skip(self, size: int) -> None:
        self.take(f"<{size}x")

    def name(self) -> str:
        end = self.data.find(b"\0", self.offset)
        if end < 0:
            raise CaptureError(f"{self.path} is truncated (an image name has no end): re-export the model.")
        raw = self.data[self.offset:end]
        self.offset = end + 1
        return raw.decode("utf-8", errors="replace")


def _read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
    reader = _Reader(path)
    (count,) = reader.take("<Q")
    cameras = {}
    for _ in range(count):
        camera_id, model_id, width, height = reader.take("<IiQQ")
        if model_id not in CAMERA_MODELS:
            raise CaptureError(f"{path}: camera {camera_id} has unknown camera model id {model_id} (a newer "
                               "COLMAP?): export the model with a PINHOLE or OPENCV camera.")
        model, num_params = CAMERA_MODELS[model_id]
        params = np.array(reader.take(f"<{num_params}d"), dtype=np.float64)
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    return cameras


def _read_images_binary(path: Path) -> list[ColmapImage]:
    reader = _Reader(path)
    (count,) = reader.take("<Q")
    images = []
    for _ in range(count):
        image_id, qw, qx, qy, qz, tx, ty, tz, camera_id = reader.take("<I7dI")
        name = reader.name()
        (num_points,) = reader.take("<Q")
        reader.skip(24 * num_points)  # (x, y, point3D_id) per 2D point: not needed for poses
        images.append(ColmapImage(image_id, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]), camera_id, name))
    return images


def _read_points_text(path: Path) -> ColmapPoints:
    xyz, rgb = [], []
    for number, line in _data_lines(path):
        if not line or line.startswith("#"):
            continue
        fields = line.split()
        try:
            xyz.append([float(v) for v in fields[1:4]])
            rgb.append([int(v) for v in fields[4:7]])
        except ValueError as error:
            raise _bad_line(path, number, str(error)) from error
        if len(xyz[-1]) != 3 or len(rgb[-1]) != 3:
            raise _bad_line(path, number, "a point needs an id, X Y Z and R G B")
        if not all(0 <= v <= 255 for v in rgb[-1]):
            raise _bad_line(path, number, f"colour {rgb[-1]} is outside 0..255")
    return ColmapPoints(np.array(xyz, dtype=np.float64).reshape(-1, 3), np.array(rgb, dtype=np.uint8).reshape(-1, 3))


def _read_points_binary(path: Path) -> ColmapPoints:
    reader = _Reader(path)
    (count,) = reader.take("<Q")
    if count * struct.calcsize("<Q3d3BdQ") > len(reader.data):  # before allocating for a bogus count
        raise CaptureError(f"{path} is truncated or not a COLMAP binary file (it claims {count} points in "
                           f"{len(reader.data)} bytes): re-export the model with COLMAP.")
    xyz = np.empty((count, 3), dtype=np.float64)
    rgb = np.empty((count, 3), dtype=np.uint8)
    for i in range(count):
        _point_id, x, y, z, r, g, b, _error, track_length = reader.take("<Q3d3BdQ")
        xyz[i] = (x, y, z)
        rgb[i] = (r, g, b)
        reader.skip(8 * track_length)  # (image_id, point2D_idx) per observation: not needed
    return ColmapPoints(xyz, rgb)
