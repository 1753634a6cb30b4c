"""Loader for Record3D's exports (format "record3d"), an iPhone/iPad app.

The app's ".r3d" export is a zip (unpacked by `load_capture` first, `archive.py`) holding:

    metadata        JSON: `w`, `h` (photo size), `K` (9 numbers, the 3x3 intrinsics in COLUMN-major
                    order: fx 0 0 0 fy 0 cx cy 1), `poses` (one [qx, qy, qz, qw, px, py, pz] per frame:
                    ARKit's camera-to-world rotation quaternion, scalar last, and position in metres),
                    `fps`, `dw`, `dh` (depth map size), and in recent versions `frameTimestamps` (s) and
                    `perFrameIntrinsicCoeffs` ([fx, fy, cx, cy] per frame)
    rgbd/N.jpg      photo of frame N (N = 0, 1, ...: the index into `poses`)
    rgbd/N.depth    its LiDAR (or TrueDepth) depth: LZFSE-compressed float32 metres, dh rows of dw
    rgbd/N.conf     its confidence, LZFSE-compressed uint8 (0 low, 1 medium, 2 high), LiDAR only

Record3D publishes no specification; the layout is the app author's (github.com/marek-simonik/record3d
issues #27, #33, #36, #63, #83, #93, #95: order [qx, qy, qz, qw, px, py, pz], camera-to-world, OpenGL
camera axes, K of the first frame) and agrees with nerfstudio's process_data/record3d_utils.py and
viser's Record3D loader (K transposed, the same pose convention, .depth/.conf as above). The photos
are portrait before app version 1.10.1 and may be landscape since; K, w, h and the poses' camera axes
describe the photos as stored. Poses are ARKit tracking (`arkit.arkit_to_engine`), with two
differences the author states:
- the world is not gravity's: the recording starts at the "zero" pose (the metadata's `initPose` is
  [0, 0, 0, 1, 0, 0, 0]), so the world's axes are the first frame's camera axes and its "up" is only
  as level as the phone was then. When the first pose is that zero pose, the world is levelled here:
  turned about a horizontal axis so that up is +Z, up from the photos' vertical lines
  (`vertical_lines.py`) or, when they show too few, the cameras' mean up (people hold the
  phone upright, but often tilted down), with a note saying which and by how much;
- front-camera (TrueDepth) recordings have no tracking: every pose is the zero pose. They are refused
  with what to do instead.
The app records at up to 60 frames per second, so frames about 1/fps s apart are kept
(`LoadOptions.fps`, 2 per second by default, the rate of a video's frames). A photo without a usable
pose is skipped with a warning naming `metadata`; a photo whose depth is missing or unreadable is
used without it.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..errors import CaptureError, PoseError
from ..geometry.cameras import mean_up_direction, rotation_taking
from ..jobs import CancelToken, ProgressFn
from .vertical_lines import up_from_vertical_lines
from .arkit import arkit_to_engine, finish_phone_capture, frames_of_photos
from .checks import SkippedPhotos, inspect_images
from .geometry import PoseRepairs, pinhole
from .model import Capture, Frame, SensorDepth
from .naming import name_list
from .options import LoadOptions
from .stray_scanner import frames_at_rate, quaternion_transform

APP = "Record3D"
METADATA = "metadata"
_PHOTO = re.compile(r"^(\d+)\.jpe?g$", re.IGNORECASE)
# Record3D's recording rate when the metadata states neither timestamps nor fps (its LiDAR default).
_FALLBACK_FPS = 60.0
_ZERO_POSE = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])  # [qx, qy, qz, qw, px, py, pz]: the recording's start
_ADVICE = "export the recording from Record3D again (Export > .r3d) and choose the .r3d file"


def is_record3d_folder(path: Path) -> bool:
    """An unpacked .r3d export: a `metadata` file beside an `rgbd/` folder."""
    return (path / METADATA).is_file() and (path / "rgbd").is_dir()


def _read_metadata(path: Path) -> dict[str, Any]:
    """The metadata JSON object; CaptureError naming the file when it is unreadable or not JSON."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise CaptureError(f"cannot read {path}: {error.strerror or error}.") from error
    except ValueError as error:  # invalid JSON or invalid UTF-8
        raise CaptureError(f"{path} is not valid JSON ({error}): the export is damaged; {_ADVICE}.") from error
    if not isinstance(data, dict):
        raise CaptureError(f"{path} is not a JSON object: the export is damaged; {_ADVICE}.")
    if not isinstance(data.get("poses"), list):
        raise CaptureError(f"{path} has no `poses` list (the camera pose of every frame): the export is damaged or "
                           f"comes from another app; {_ADVICE}.")
    return data


def _positive_number(data: dict[str, Any], key: str) -> Optional[float]:
    value = data.get(key)
    if isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value) and value > 0:
        return float(value)
    return None


def _shared_K(data: dict[str, Any], path: Path) -> Optional[np.ndarray]:
    """K (3, 3) from `K` (column-major), None when absent; CaptureError naming the file when malformed."""
    if "K" not in data:
        return None
    try:
        K = np.array(data["K"], dtype=np.float64).reshape(3, 3).T  # column-major: the transpose of a row-major read
    except (TypeError, ValueError) as error:
        raise CaptureError(f"{path}: `K` is not 9 numbers ({error}); {_ADVICE}.") from error
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CaptureError(f"{path}: `K` has no positive focal length ({data['K']}); {_ADVICE}.")
    return K


def _frame_K(data: dict[str, Any], index: int, shared: Optional[np.ndarray]) -> np.ndarray:
    """K (3, 3) of frame `index`: its `perFrameIntrinsicCoeffs` entry when the metadata has them (ARKit
    refines the focal length during a recording), else the shared `K`. ValueError saying why."""
    per_frame = data.get("perFrameIntrinsicCoeffs")
    if isinstance(per_frame, list) and index < len(per_frame):
        try:
            fx, fy, cx, cy = (float(value) for value in per_frame[index])
        except (TypeError, ValueError) as error:
            raise ValueError(f"perFrameIntrinsicCoeffs[{index}] is not 4 numbers") from error
        if np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0:
            return pinhole(fx, fy, cx, cy)
        raise ValueError(f"perFrameIntrinsicCoeffs[{index}] has no positive focal length")
    if shared is None:
        raise ValueError("no intrinsics (neither K nor perFrameIntrinsicCoeffs)")
    return shared.copy()


def _frame_pose(entry: Any, index: int, repairs: PoseRepairs) -> np.ndarray:
    """Engine pose (4, 4) of poses[index] = [qx, qy, qz, qw, px, py, pz]; ValueError saying why not."""
    if not isinstance(entry, list) or len(entry) != 7:
        raise ValueError(f"poses[{index}] is not 7 numbers")
    try:
        values = [float(value) for value in entry]
    except (TypeError, ValueError) as error:
        raise ValueError(f"poses[{index}] is not 7 numbers") from error
    transform, deviation = quaternion_transform(values[:4], values[4:])
    return arkit_to_engine(repairs.make_rigid(transform, f"poses[{index}]", deviation))


def _is_zero_pose(entry: Any) -> bool:
    """Whether a `poses` entry is Record3D's starting pose [0, 0, 0, 1, 0, 0, 0] (no rotation, at the
    origin): the first frame of a recording, or every frame of one without tracking."""
    try:
        return bool(np.allclose(np.asarray(entry, dtype=np.float64), _ZERO_POSE, atol=1e-6))
    except (TypeError, ValueError):  # a malformed entry, reported where the poses are read
        return False


def _levelled(frames: list[Frame]) -> tuple[list[Frame], str]:
    """`frames` turned about a horizontal axis through the origin so that up is +Z, and a note saying
    how: up from the photos' vertical lines when they show enough, else the mean of the cameras' up
    vectors (-y, OpenCV axes). The smallest such rotation, so the heading is kept. Frames whose up
    vectors cancel out are returned unchanged."""
    try:
        mean_up = mean_up_direction(np.stack([f.pose for f in frames]))
    except PoseError:
        return frames, "Record3D's world starts at the first frame's camera, not at gravity, and the cameras point every way: not levelled"
    lines = up_from_vertical_lines(frames, mean_up)
    up = lines.up if lines is not None else mean_up
    turn = np.eye(4)
    turn[:3, :3] = rotation_taking(up, np.array([0.0, 0.0, 1.0]))
    tilt = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    how = lines.describe() if lines is not None else "the cameras' mean up"
    return ([replace(f, pose=turn @ f.pose) for f in frames],
            f"Record3D's world starts at the first frame's camera, not at gravity: levelled by {how} (turned {tilt:.1f} deg)")


def _frame_times(data: dict[str, Any], indices: list[int], warnings: list[str]) -> list[float]:
    """Seconds of each frame index: `frameTimestamps` when the metadata has one per pose, else index / fps."""
    stamps = data.get("frameTimestamps")
    if isinstance(stamps, list) and len(stamps) == len(data["poses"]):
        try:
            return [float(stamps[i]) for i in indices]
        except (TypeError, ValueError):  # damaged timestamps: the frame rate still places the frames
            warnings.append(f"{METADATA}'s frameTimestamps are not all numbers: frames placed by its fps instead")
    fps = _positive_number(data, "fps")
    if fps is None:
        warnings.append(f"{METADATA} states neither frameTimestamps nor fps: assumed {_FALLBACK_FPS:g} frames per "
                        "second")
        fps = _FALLBACK_FPS
    return [i / fps for i in indices]


def _depth_size(data: dict[str, Any]) -> Optional[tuple[int, int]]:
    """(dw, dh) of the depth maps, or None when the metadata does not state both."""
    dw, dh = _positive_number(data, "dw"), _positive_number(data, "dh")
    return (int(dw), int(dh)) if dw is not None and dh is not None else None


def load_record3d(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
                  cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "record3d") of an unpacked Record3D export folder `path` (metadata + rgbd/)."""
    metadata_path = path / METADATA
    data = _read_metadata(metadata_path)
    shared_K = _shared_K(data, metadata_path)
    stated_w, stated_h = _positive_number(data, "w"), _positive_number(data, "h")
    stated_size = (int(stated_w), int(stated_h)) if stated_w and stated_h else None
    rgbd = path / "rgbd"
    photos = sorted((int(match.group(1)), p) for p in rgbd.iterdir() if (match := _PHOTO.match(p.name)))
    if not photos:
        raise CaptureError(f"{rgbd} holds no N.jpg photos: the export has no colour frames; {_ADVICE}.")

    poses = data["poses"]
    warnings: list[str] = []
    repairs = PoseRepairs()
    without_pose, bad_frames = [], []
    posed: list[tuple[int, Path, np.ndarray, np.ndarray]] = []  # (index, photo, pose, K)
    for index, photo in photos:
        if index >= len(poses):
            without_pose.append(f"rgbd/{photo.name}")
            continue
        try:
            posed.append((index, photo, _frame_pose(poses[index], index, repairs), _frame_K(data, index, shared_K)))
        except ValueError as error:
            bad_frames.append(f"rgbd/{photo.name} ({error})")
    if without_pose:
        warnings.append(f"{METADATA} has {len(poses)} poses but rgbd/ holds {len(photos)} photos: the "
                        f"{len(without_pose)} photo(s) past the last pose are skipped: {name_list(without_pose)}")
    if bad_frames:
        warnings.append(f"{len(bad_frames)} frame(s) have an unusable pose or intrinsics in {METADATA}, skipped: "
                        f"{name_list(bad_frames)}")
    if repairs.warning():
        warnings.append(f"{metadata_path}: {repairs.warning()}")
    if not posed:
        raise CaptureError(f"no photo of {path} has a usable pose and intrinsics in {METADATA} "
                           f"({'; '.join(warnings) or 'its poses list is empty'}): {_ADVICE}.")
    if len(posed) > 1 and all(_is_zero_pose(poses[index]) for index, _, _, _ in posed):
        raise CaptureError(f"every pose in {metadata_path} is [0, 0, 0, 1, 0, 0, 0]: Record3D tracks the camera only "
                           "in recordings with the rear (LiDAR) camera, not the front (TrueDepth) one. Record the room "
                           f"again with the rear camera, or choose the folder {rgbd} to load the photos without poses "
                           "(structure from motion then estimates them).")
    times = _frame_times(data, [index for index, _, _, _ in posed], warnings)
    kept = [posed[i] for i in frames_at_rate(times, options.fps)]
    depth_size = _depth_size(data)
    entries: list[tuple[Path, np.ndarray, np.ndarray, Optional[SensorDepth]]] = []
    no_depth = []
    for index, photo, pose, K in kept:
        depth, confidence = rgbd / f"{index}.depth", rgbd / f"{index}.conf"
        sensor = None
        if not depth.is_file():
            no_depth.append(f"rgbd/{photo.name}")
        elif depth_size is not None:  # the .depth files do not store their size
            sensor = SensorDepth(depth, "r3d", confidence if confidence.is_file() else None, size=depth_size)
        entries.append((photo, pose, K, sensor))
    with_depth = len(entries) - len(no_depth)
    if with_depth and depth_size is None:
        warnings.append(f"{METADATA} does not state the depth maps' size (dw, dh): the depth maps are not used")
    elif no_depth and with_depth:  # an export without any depth (a phone without LiDAR) is no problem
        warnings.append(f"{len(no_depth)} photo(s) have no rgbd/N.depth, used without depth: {name_list(no_depth)}")

    skipped = SkippedPhotos()
    infos = inspect_images([photo for photo, _, _, _ in entries], skipped, verify=options.verify_images,
                           progress=progress, cancel=cancel)
    frames, usable_infos = frames_of_photos([(photo, pose, K, stated_size, sensor) for photo, pose, K, sensor in entries],
                                            infos, skipped, lambda photo: METADATA, warnings)
    capture = finish_phone_capture(path, "record3d", APP, frames, usable_infos, path, options, warnings, skipped)
    if _is_zero_pose(poses[0]) and capture.frames:  # the world is the first frame's camera, not gravity's (see above)
        capture.frames, note = _levelled(capture.frames)
        capture.notes.append(note)
    if len(kept) < len(posed):
        capture.notes.append(f"{len(kept)} of the {len(posed)} posed frames kept (about {options.fps:g} per second)")
    return capture
