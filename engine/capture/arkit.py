"""ARKit's camera and world conventions, mapped to the engine's in this one place.

Every iPhone/iPad scanning app (3D Scanner App, Stray Scanner, Record3D, Polycam) exports ARKit's
own tracking:
- a camera-to-world transform per frame, camera axes x right, y up, z backward (OpenGL's);
- a world in metres with gravity along -y (y up), x and z horizontal, its origin and heading where
  the session started;
- intrinsics in pixels of the captured image in the sensor's landscape orientation.
The engine's world is Z up with OpenCV camera axes (x right, y down, z forward), so

    pose_engine = Y_UP_TO_Z_UP @ pose_arkit @ diag(1, -1, -1, 1)

which keeps the scale (metres) and turns ARKit's up (+y) into the engine's (+Z).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from .checks import SkippedPhotos, finish_capture
from .geometry import fit_intrinsics, opengl_to_opencv, quaternion_to_rotation
from .images import ImageInfo, UnusableImage
from .model import Capture, Frame, SensorDepth
from .options import LoadOptions
from .sensor_depth import check_sensor_depths

# World rotation taking ARKit's y-up axes to the engine's Z up: x -> x, y -> z, z -> -y (a rotation
# of +90 deg about x; determinant +1, so handedness is kept).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0, 0.0],
                         [0.0, 0.0, -1.0, 0.0],
                         [0.0, 1.0, 0.0, 0.0],
                         [0.0, 0.0, 0.0, 1.0]])

ARKIT_POSES = "ARKit"  # Capture.pose_origin prefix: "ARKit (3D Scanner App)"


def pose_origin(app: str) -> str:
    """What reports say made a phone app's poses: "ARKit (3D Scanner App)"."""
    return f"{ARKIT_POSES} ({app})"


def arkit_to_engine(pose: np.ndarray) -> np.ndarray:
    """(4, 4) float64 engine pose (OpenCV camera axes, Z-up world) of an ARKit camera-to-world
    transform (4, 4): camera x right / y up / z backward, world y up, metres."""
    return Y_UP_TO_Z_UP @ opengl_to_opencv(np.asarray(pose, dtype=np.float64))


def transform_from_quaternion_xyzw(quaternion_xyzw: np.ndarray, position: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world from a rotation quaternion (4,) ordered (x, y, z, w), as ARKit-based apps
    write it, and a position (3,). Not normalised here: callers check |q| so a corrupt line is refused
    (`geometry.quaternion_deviation`)."""
    x, y, z, w = np.asarray(quaternion_xyzw, dtype=np.float64)
    transform = np.eye(4)
    transform[:3, :3] = quaternion_to_rotation(np.array([w, x, y, z]))  # takes COLMAP's (w, x, y, z)
    transform[:3, 3] = np.asarray(position, dtype=np.float64)
    return transform


def finish_phone_capture(root: Path, format: str, app: str, frames: list[Frame], infos: list[ImageInfo], where: Path,
                         options: LoadOptions, warnings: list[str], skipped: SkippedPhotos,
                         what: str = "posed photo") -> Capture:
    """The common tail of the phone apps' loaders: unreadable depth maps dropped with a warning (when
    the options verify files), metric unless the options say otherwise, `checks.finish_capture`, and
    the poses' origin "ARKit (<app>)". `frames` and `infos` correspond one to one."""
    if options.verify_images:
        frames = check_sensor_depths(frames, warnings)
    metric = True if options.metric is None else options.metric
    capture = finish_capture(root, format, frames, infos, where, metric, warnings, skipped, what=what)
    capture.pose_origin = pose_origin(app)
    return capture


def read_json_object(path: Path) -> dict[str, Any]:
    """The JSON object in `path` (an app's per-frame camera file); ValueError saying what is wrong, for
    the loader's warning naming the file."""
    try:
        data: Any = json.loads(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise ValueError(f"cannot read it: {error.strerror or error}") from error
    except ValueError as error:
        raise ValueError(f"not valid JSON ({error})") from error
    if not isinstance(data, dict):
        raise ValueError("not a JSON object")
    return data


# (photo, engine pose (4, 4), K (3, 3), the (width, height) K was stated for or None, its sensor depth)
PhotoEntry = tuple[Path, np.ndarray, np.ndarray, Optional[tuple[int, int]], Optional[SensorDepth]]


def frames_of_photos(entries: list[PhotoEntry], infos: list[Optional[ImageInfo]], skipped: SkippedPhotos,
                     source: Callable[[Path], str], warnings: list[str]) -> tuple[list[Frame], list[ImageInfo]]:
    """Frames (and their infos) of the photos that could be read (`infos[i]` not None), K fitted to each
    photo's size where a size was stated (`geometry.fit_intrinsics`; `source(photo)` names the file that
    stated it). A photo of another aspect ratio than stated is added to `skipped`; a uniform rescale adds
    one warning to `warnings`."""
    frames, usable, scaled = [], [], []
    for (photo, pose, K, stated_size, sensor), info in zip(entries, infos):
        if info is None:
            continue
        if stated_size is not None:
            try:
                K, warning = fit_intrinsics(K, stated_size, info.size, photo, source(photo))
            except UnusableImage as error:
                skipped.add(error)
                continue
            if warning and not scaled:
                scaled.append(warning)
        frames.append(Frame(image_path=photo, width=info.width, height=info.height, K=K, pose=pose,
                            sensor_depth=sensor))
        usable.append(info)
    warnings += scaled
    return frames, usable
