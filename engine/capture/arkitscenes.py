"""Loader for ARKitScenes' raw layout (format "arkitscenes"): Apple's public iPad captures of real rooms.

One video's frames folder (`<video_id>_frames/`, or the video's folder holding it):

    lowres_wide/<id>_<t>.png               RGB photos, 256 x 192, t the frame's time in seconds (3 decimals)
    lowres_wide_intrinsics/<id>_<t>.pincam  one line "width height fx fy cx cy" per photo
    lowres_wide.traj                        one line per tracked frame: t, rotation (axis-angle, 3), translation
                                            (3), the world-to-camera transform of the camera at time t
    lowres_depth/<id>_<t>.png               LiDAR depth, 16-bit millimetres, registered to the photo
    confidence/<id>_<t>.png                 its confidence, ARKit's 0 low / 1 medium / 2 high (when downloaded)

Conventions, checked on scene 40777060 (its LiDAR back-projected with them gives one consistent room
with a level floor): the camera axes are OpenCV's (ARKitScenes' own depth-to-points code uses K as it
is), the world is metres with gravity along -z, so poses are the engine's once inverted. The photos are
stored as the sensor delivered them: an iPad held upright gives photos turned a quarter turn. They are
turned upright here (`upright_quarter_turns` from the poses), with their intrinsics, poses and depth
maps, into the cache (`cache.py`): the network and structure from motion expect upright photos, and
SfM of the photos alone takes "up" from how they were held.

A photo is matched to the trajectory sample nearest its time, within TIME_TOLERANCE_S (ARKitScenes'
own loaders do the same); one without a sample there, or without intrinsics, is skipped with a warning.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from ..geometry.cameras import turned_clockwise, upright_quarter_turns
from ..jobs import CancelToken, ProgressFn, check, report
from .arkit import finish_phone_capture
from .cache import cache_folder, read_manifest, reset_folder, source_stamp, write_manifest
from .checks import SkippedPhotos, inspect_images
from .geometry import PoseRepairs, camera_to_world_from_world_to_camera, pinhole
from .model import Capture, Frame, SensorDepth
from .naming import name_list
from .options import LoadOptions

APP = "ARKitScenes"
TIME_TOLERANCE_S = 0.005
PHOTOS, INTRINSICS, TRAJECTORY = "lowres_wide", "lowres_wide_intrinsics", "lowres_wide.traj"
DEPTH, CONFIDENCE = "lowres_depth", "confidence"
_PHOTO = re.compile(r"^(?P<video>\w+?)_(?P<time>\d+(?:\.\d+)?)\.png$", re.IGNORECASE)
_ADVICE = ("download the video again with ARKitScenes' download_data.py (raw, assets lowres_wide, "
           "lowres_wide_intrinsics, lowres_wide.traj and lowres_depth)")


def frames_folder(path: Path) -> Optional[Path]:
    """The folder holding lowres_wide/ and lowres_wide.traj: `path` itself or its one `*_frames` folder."""
    candidates = [path] + sorted(p for p in path.glob("*_frames") if p.is_dir())
    for folder in candidates:
        if (folder / PHOTOS).is_dir() and (folder / TRAJECTORY).is_file():
            return folder
    return None


def is_arkitscenes_folder(path: Path) -> bool:
    return path.is_dir() and frames_folder(path) is not None


def read_trajectory(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(times (N,) seconds, camera-to-world poses (N, 4, 4)) of a lowres_wide.traj, sorted by time;
    CaptureError naming the line when one is not seven numbers."""
    import cv2  # defers cv2 (OpenCV) off the light paths
    times, poses = [], []
    for number, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            values = [float(v) for v in line.split()]
        except ValueError:
            values = []
        if len(values) != 7 or not np.all(np.isfinite(values)):
            raise CaptureError(f"{path}, line {number}: expected 7 numbers (time, axis-angle rotation, translation), "
                               f"found {line.strip()[:80]!r}: {_ADVICE}.")
        rotation, _ = cv2.Rodrigues(np.array(values[1:4], dtype=np.float64))
        times.append(values[0])
        poses.append(camera_to_world_from_world_to_camera(rotation, np.array(values[4:7])))
    if not times:
        raise CaptureError(f"{path} holds no camera poses: {_ADVICE}.")
    order = np.argsort(times)
    return np.asarray(times)[order], np.stack(poses)[order]


def read_pincam(path: Path) -> tuple[np.ndarray, tuple[int, int]]:
    """(K (3, 3), (width, height)) of one .pincam file; ValueError saying what is wrong."""
    try:
        values = [float(v) for v in path.read_text(encoding="utf-8").split()]
    except (OSError, ValueError) as error:
        raise ValueError(f"unreadable ({error})") from error
    if len(values) != 6 or min(values[:4]) <= 0:
        raise ValueError(f"expected 'width height fx fy cx cy', found {values}")
    width, height, fx, fy, cx, cy = values
    return pinhole(fx, fy, cx, cy), (int(width), int(height))


def _turned_file(source: Path, target: Path, quarter_turns: int) -> None:
    import cv2  # defers cv2 (OpenCV) off the light paths
    image = cv2.imread(str(source), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"cannot decode {source}")
    if not cv2.imwrite(str(target), np.ascontiguousarray(np.rot90(image, -quarter_turns))):
        raise ValueError(f"cannot write {target}")


def turn_files(folder: Path, frames: list[Frame], quarter_turns: int, cache_dir: Optional[Path],
               progress: Optional[ProgressFn], cancel: Optional[CancelToken]) -> list[Frame]:
    """`frames` with photos, depth and confidence turned upright into the cache (reused while the
    sources are unchanged), their K and pose turned with them."""
    sources = [f.image_path for f in frames] + [p for f in frames if f.sensor_depth is not None
                                                for p in (f.sensor_depth.path, f.sensor_depth.confidence_path) if p]
    target = cache_folder(folder, f"arkitscenes-upright-{quarter_turns}", cache_dir)
    key = {"sources": source_stamp(sources), "quarter_turns": quarter_turns}
    done = read_manifest(target, key) is not None
    if not done:
        reset_folder(target)
    turned = []
    for index, frame in enumerate(frames):
        check(cancel)
        report(progress, "Turning photos upright", index, len(frames))
        photo = target / PHOTOS / frame.image_path.name
        sensor = frame.sensor_depth
        if sensor is not None:
            sensor = SensorDepth(target / DEPTH / sensor.path.name, sensor.encoding,
                                 target / CONFIDENCE / sensor.confidence_path.name if sensor.confidence_path else None)
        if not done:
            pairs = [(frame.image_path, photo)]
            if sensor is not None:
                pairs.append((frame.sensor_depth.path, sensor.path))
                if sensor.confidence_path is not None:
                    pairs.append((frame.sensor_depth.confidence_path, sensor.confidence_path))
            for source, copy in pairs:
                copy.parent.mkdir(parents=True, exist_ok=True)
                _turned_file(source, copy, quarter_turns)
        K, pose, (width, height) = turned_clockwise(frame.K, frame.pose, (frame.width, frame.height), quarter_turns)
        turned.append(Frame(image_path=photo, width=width, height=height, K=K, pose=pose, sensor_depth=sensor))
    report(progress, "Turning photos upright", len(frames), len(frames))
    if not done:
        write_manifest(target, key, {"frames": len(frames)})
    return turned


def load_arkitscenes(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
                     cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "arkitscenes") of an ARKitScenes video's raw folder, photos upright, metric."""
    folder = frames_folder(path)
    if folder is None:
        raise CaptureError(f"{path} is not an ARKitScenes video folder (lowres_wide/ beside lowres_wide.traj): {_ADVICE}.")
    photos = []
    for photo in (folder / PHOTOS).iterdir():
        match = _PHOTO.match(photo.name)
        if match:
            photos.append((float(match.group("time")), photo))
    photos.sort()
    if not photos:
        raise CaptureError(f"{folder / PHOTOS} holds no <video>_<time>.png photos: {_ADVICE}.")
    times, poses = read_trajectory(folder / TRAJECTORY)
    repairs = PoseRepairs()
    no_pose, no_intrinsics, no_depth = [], [], []
    entries: list[tuple[Path, np.ndarray, np.ndarray, tuple[int, int], Optional[SensorDepth]]] = []
    for time, photo in photos:
        nearest = int(np.argmin(np.abs(times - time)))
        if abs(times[nearest] - time) > TIME_TOLERANCE_S:
            no_pose.append(photo.name)
            continue
        pincam = folder / INTRINSICS / f"{photo.stem}.pincam"
        try:
            K, stated_size = read_pincam(pincam)
        except ValueError as error:
            no_intrinsics.append(f"{photo.name} ({pincam.name}: {error})")
            continue
        depth, confidence = folder / DEPTH / photo.name, folder / CONFIDENCE / photo.name
        sensor = None
        if depth.is_file():
            sensor = SensorDepth(depth, "png_mm", confidence if confidence.is_file() else None)
        else:
            no_depth.append(photo.name)
        entries.append((photo, repairs.make_rigid(poses[nearest], f"{TRAJECTORY} at {times[nearest]:.3f} s"), K,
                        stated_size, sensor))

    warnings: list[str] = []
    if no_pose:
        warnings.append(f"{len(no_pose)} photo(s) have no pose in {TRAJECTORY} within {1000 * TIME_TOLERANCE_S:g} ms "
                        f"of their time, skipped: {name_list(no_pose)}")
    if no_intrinsics:
        warnings.append(f"{len(no_intrinsics)} photo(s) have no usable {INTRINSICS}/*.pincam, skipped: "
                        f"{name_list(no_intrinsics)}")
    if repairs.warning():
        warnings.append(f"{folder / TRAJECTORY}: {repairs.warning()}")
    if no_depth and len(no_depth) < len(entries):
        warnings.append(f"{len(no_depth)} photo(s) have no {DEPTH}/ map, used without depth: {name_list(no_depth)}")
    if not entries:
        raise CaptureError(f"no photo of {folder} has both a pose and intrinsics ({'; '.join(warnings)}): {_ADVICE}.")

    skipped = SkippedPhotos()
    infos = inspect_images([photo for photo, *_ in entries], skipped, verify=options.verify_images,
                           progress=progress, cancel=cancel)
    frames, usable, turns = [], [], 0
    for (photo, pose, K, stated_size, sensor), info in zip(entries, infos):
        if info is None:
            continue
        if info.size != stated_size:
            warnings.append(f"{photo.name} is {info.width} x {info.height} but its .pincam says "
                            f"{stated_size[0]} x {stated_size[1]}: skipped")
            continue
        frames.append(Frame(image_path=photo, width=info.width, height=info.height, K=K, pose=pose, sensor_depth=sensor))
        usable.append(info)
    if frames:
        turns = upright_quarter_turns(np.stack([f.pose for f in frames]))
        if turns:
            frames = turn_files(folder, frames, turns, options.cache_dir, progress, cancel)
            # the sizes the resolution check compares are the turned photos'; duplicates keep their digests
            usable = [replace(info, path=f.image_path, width=f.width, height=f.height) for info, f in zip(usable, frames)]
    capture = finish_phone_capture(path, "arkitscenes", APP, frames, usable, folder, options, warnings, skipped)
    if frames and turns:
        capture.notes.append(f"the photos are stored turned: turned upright ({90 * turns} deg clockwise), with their "
                             f"depth maps, into {frames[0].image_path.parent.parent}")
    return capture
