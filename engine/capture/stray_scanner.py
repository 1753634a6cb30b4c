"""Loader for Stray Scanner's recordings (format "strayscanner"), an iPhone/iPad app (StrayRobots/scanner).

A recording is a folder named after a hash (`71de12f9/`), as the app writes it (docs/format.md and
StrayScanner/Helpers/*Encoder.swift in github.com/strayrobots/scanner):

    rgb.mp4                 HEVC video of the camera's frames in the sensor's landscape orientation
                            (1920 x 1440), one video frame per recorded frame, in frame order
    odometry.csv            header `timestamp, frame, x, y, z, qx, qy, qz, qw`, then one row per frame:
                            ARKit timestamp (s), frame number (`000005`), camera position (metres,
                            ARKit world) and rotation quaternion (x, y, z, w), camera-to-world
    camera_matrix.csv       K (3 rows of 3 comma-separated numbers), pixels of the video's frames
    depth/NNNNNN.png        LiDAR depth of frame NNNNNN, 16-bit millimetres, 256 x 192
    confidence/NNNNNN.png   its confidence (0 low, 1 medium, 2 high)
    imu.csv                 accelerometer and gyroscope readings (not read)

The quaternion is not ARKit's camera orientation as it is: the app multiplies it by a half turn about
the camera's x axis before writing it (OdometryEncoder.swift: `q_WA * q_AC`, `q_AC = (1, 0, 0, 0)`),
so its camera axes are OpenCV's (x right, y down, z forward) in ARKit's y-up world. That turn is undone
here and the result mapped by `arkit.arkit_to_engine`, like every ARKit app's poses.

Frames: the video's k-th frame is the frame numbered k (the app appends one video frame per odometry
row). The video is decoded in order and frames about 1/fps s apart by the odometry timestamps
(`LoadOptions.fps`, 2 per second by default) are written as JPEG (quality 95) into the cache
(`cache.py`); blurry ones are dropped as for any video (`video.py`). Each frame keeps the depth map of
its own number. A frame whose odometry row is unusable is skipped with a warning naming the line; a
video and an odometry file of different lengths are used as far as both go, with a warning.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn, check, report
from .arkit import arkit_to_engine, finish_phone_capture, transform_from_quaternion_xyzw
from .cache import cache_folder, read_manifest, reset_folder, source_stamp, write_manifest
from .checks import SkippedPhotos, inspect_images
from .geometry import ROTATION_TOLERANCE, PoseRepairs, quaternion_deviation
from .model import Capture, Frame, SensorDepth
from .naming import name_list
from .options import LoadOptions
from .video import blurry_frames, write_frame

APP = "Stray Scanner"
VIDEO = "rgb.mp4"
ODOMETRY = "odometry.csv"
CAMERA_MATRIX = "camera_matrix.csv"
_POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")
# The half turn about the camera's x axis that the app applies to ARKit's rotation (q_AC); it is its
# own inverse, so multiplying by it again gives ARKit's camera axes (x right, y up, z backward) back.
_APP_CAMERA_TURN = np.diag([1.0, -1.0, -1.0, 1.0])


def is_stray_scanner_folder(path: Path) -> bool:
    """A Stray Scanner recording: rgb.mp4 beside odometry.csv or camera_matrix.csv (either one, so a
    recording that lost the other is still recognised and its loader says which file is missing)."""
    return (path / VIDEO).is_file() and ((path / ODOMETRY).is_file() or (path / CAMERA_MATRIX).is_file())


def quaternion_transform(quaternion_xyzw: Sequence[float], position: Sequence[float]) -> tuple[np.ndarray, float]:
    """(camera-to-world (4, 4), |q|^2 - 1 deviation) from a quaternion (4,) ordered (x, y, z, w) and a
    position (3,); ValueError saying why when the quaternion is not close to unit length (a corrupt
    row: a zero quaternion carries no rotation at all)."""
    quaternion = np.asarray(quaternion_xyzw, dtype=np.float64)
    deviation = quaternion_deviation(quaternion)
    if deviation > ROTATION_TOLERANCE:
        raise ValueError(f"quaternion {quaternion.tolist()} is not of unit length (|q|^2 - 1 = {deviation:.2g})")
    position = np.asarray(position, dtype=np.float64)
    if not np.all(np.isfinite(position)):
        raise ValueError(f"position {position.tolist()} is not finite")
    return transform_from_quaternion_xyzw(quaternion, position), deviation


def frames_at_rate(times: Sequence[float], fps: float) -> list[int]:
    """Indices of the frames to keep, about 1/`fps` s apart: the first frame at or after each sample
    time, starting with the first frame (the schedule of `video.py`). `times` (N,) in seconds,
    increasing."""
    step = 1.0 / fps
    kept: list[int] = []
    next_time: Optional[float] = None
    for index, time in enumerate(times):
        if next_time is None:
            kept.append(index)
            next_time = time + step
        elif time + 1e-6 >= next_time:
            kept.append(index)
            next_time += step
        while next_time <= time:  # keep the schedule across gaps (dropped frames, a paused recording)
            next_time += step
    return kept


def _read_camera_matrix(path: Path) -> np.ndarray:
    """K (3, 3) from camera_matrix.csv; CaptureError naming the file when it is not a camera matrix."""
    advice = "copy the recording folder from the phone again (it is written when the recording stops)"
    if not path.is_file():
        raise CaptureError(f"{path} is missing: it holds the camera's intrinsics; {advice}.")
    try:
        rows = [line for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
        K = np.array([[float(value) for value in row.split(",")] for row in rows], dtype=np.float64)
    except OSError as error:
        raise CaptureError(f"cannot read {path}: {error.strerror or error}.") from error
    except ValueError as error:  # a non-number, or rows of different lengths
        raise CaptureError(f"{path} is not a 3 x 3 camera matrix of numbers ({error}): {advice}.") from error
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0 \
            or np.max(np.abs(K[2] - [0.0, 0.0, 1.0])) > 1e-6:
        raise CaptureError(f"{path} is not a camera matrix (3 rows fx 0 cx / 0 fy cy / 0 0 1 with positive focal "
                           f"lengths): {advice}.")
    return K


def _read_odometry(path: Path) -> tuple[list[tuple[int, Optional[float], np.ndarray, float]], list[str]]:
    """The rows of odometry.csv as (frame number, timestamp or None, ARKit camera-to-world (4, 4)
    with ARKit's camera axes, quaternion deviation), and "line N (why)" for each unusable row.
    CaptureError naming the file when it is missing, unreadable or lacks the pose columns."""
    if not path.is_file():
        raise CaptureError(f"{path} is missing: it holds the camera pose of every frame, without which the recording "
                           "cannot be used; copy the whole recording folder from the phone again.")
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as error:
        raise CaptureError(f"cannot read {path}: {getattr(error, 'strerror', None) or error}.") from error
    header = [name.strip().lower() for name in lines[0].split(",")] if lines else []
    missing = [name for name in _POSE_COLUMNS if name not in header]
    if missing:
        raise CaptureError(f"{path} does not start with the header `timestamp, frame, x, y, z, qx, qy, qz, qw` "
                           f"(no column {', '.join(missing)}): it is not Stray Scanner's odometry or it is damaged; "
                           "copy the recording folder from the phone again.")
    column = {name: header.index(name) for name in header}
    rows, bad = [], []
    for line_number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        fields = [field.strip() for field in line.split(",")]
        try:
            if len(fields) != len(header):
                raise ValueError(f"{len(fields)} fields, the header names {len(header)}")
            values = {name: fields[column[name]] for name in header}
            number = int(values["frame"]) if "frame" in values else len(rows) + len(bad)
            time = float(values["timestamp"]) if "timestamp" in values else None
            pose = [float(values[name]) for name in _POSE_COLUMNS]
            transform, deviation = quaternion_transform(pose[3:], pose[:3])
        except ValueError as error:
            bad.append(f"line {line_number} ({error})")
            continue
        rows.append((number, time, transform @ _APP_CAMERA_TURN, deviation))
    return rows, bad


def _video_fps(video: Path) -> float:
    """The frame rate rgb.mp4 states (for odometry files without timestamps); 60, ARKit's rate, when
    it states none."""
    import cv2  # defers cv2 (OpenCV) off the light paths

    capture = cv2.VideoCapture(str(video))
    try:
        fps = capture.get(cv2.CAP_PROP_FPS) if capture.isOpened() else 0.0
    finally:
        capture.release()
    return fps if np.isfinite(fps) and fps > 0 else 60.0


def _extract(video: Path, folder: Path, wanted: set[int], progress: Optional[ProgressFn],
             cancel: Optional[CancelToken]) -> tuple[list[tuple[int, str]], list[float], int]:
    """Writes the video frames numbered in `wanted` as JPEG into `folder`; returns (frame number, file
    name) of each written frame, their sharpness, and the number of frames the video holds."""
    import cv2  # defers cv2 (OpenCV) off the light paths

    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise CaptureError(f"cannot open video {video}: the file is damaged or its codec (HEVC) is not supported by "
                           "this OpenCV; copy the recording from the phone again.")
    # The intrinsics are for the frames as the sensor delivered them (landscape); a rotation tag in
    # the file must not turn the decoded frames.
    capture.set(cv2.CAP_PROP_ORIENTATION_AUTO, 0)
    written: list[tuple[int, str]] = []
    scores: list[float] = []
    total = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) or 0
    number = 0
    try:
        while True:
            check(cancel)
            if not capture.grab():  # grab without converting the frames that are not kept
                break
            if number in wanted:
                ok, bgr = capture.retrieve()
                if ok and bgr is not None:
                    name = f"frame_{number:06d}.jpg"
                    scores.append(write_frame(bgr, folder / name, video, number))
                    written.append((number, name))
            number += 1
            report(progress, "extracting video frames", number, max(total, number))
    finally:
        capture.release()
    if number == 0:
        raise CaptureError(f"no frame could be read from video {video}: the file is damaged or its codec (HEVC) is not "
                           "supported by this OpenCV; copy the recording from the phone again.")
    return written, scores, number


def _extracted_frames(path: Path, selected: list[int], options: LoadOptions, progress: Optional[ProgressFn],
                      cancel: Optional[CancelToken]) -> tuple[Path, dict]:
    """(cache folder, its manifest result: "frames" [[number, file name]], "video_frames", "warnings")
    for the `selected` frame numbers of rgb.mp4, extracted on first use and reused while the video
    and the odometry are unchanged."""
    video = path / VIDEO
    # Named after the recording too: with a shared cache_dir, every recording's video is rgb.mp4.
    folder = cache_folder(path, f"strayscanner-{path.name}-{options.fps:g}fps", options.cache_dir)
    key = {"version": 1, "source": source_stamp([video, path / ODOMETRY]), "fps": options.fps,
           "blur_fraction": options.blur_fraction}
    done = read_manifest(folder, key)
    if done is None:
        reset_folder(folder)
        written, scores, video_frames = _extract(video, folder, set(selected), progress, cancel)
        dropped = blurry_frames(scores, options.blur_fraction)
        for i in dropped:
            (folder / written[i][1]).unlink()
        warnings = []
        if dropped:
            warnings.append(f"{len(dropped)} of {len(written)} extracted frames dropped as blurry (sharpness under "
                            f"{options.blur_fraction:g} x the median): {name_list([written[i][1] for i in dropped])}")
        dropped_set = set(dropped)
        done = {"frames": [list(entry) for i, entry in enumerate(written) if i not in dropped_set],
                "video_frames": video_frames, "warnings": warnings}
        write_manifest(folder, key, done)
    return folder, done


def _check_principal_point(K: np.ndarray, size: tuple[int, int], path: Path) -> None:
    """CaptureError when K's principal point lies outside the frames: camera_matrix.csv states no image
    size, so this is the one sign that the video was resized or rotated after recording."""
    width, height = size
    if not (0 < K[0, 2] < width and 0 < K[1, 2] < height):
        raise CaptureError(f"{path / CAMERA_MATRIX} puts the principal point at ({K[0, 2]:g}, {K[1, 2]:g}), "
                           f"outside the {width} x {height} frames of {VIDEO}: the video was resized or rotated after "
                           "recording. Use the rgb.mp4 the app wrote.")


def load_stray_scanner(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
                       cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "strayscanner") of the Stray Scanner recording folder `path`."""
    K = _read_camera_matrix(path / CAMERA_MATRIX)
    rows, bad_rows = _read_odometry(path / ODOMETRY)
    repairs = PoseRepairs()
    usable: list[tuple[int, Optional[float], np.ndarray]] = []
    for number, time, transform, deviation in sorted(rows, key=lambda row: row[0]):
        try:
            usable.append((number, time, arkit_to_engine(repairs.make_rigid(transform, f"frame {number:06d}",
                                                                            deviation))))
        except ValueError as error:
            bad_rows.append(f"frame {number:06d} ({error})")
    warnings: list[str] = []
    if bad_rows:
        warnings.append(f"{len(bad_rows)} row(s) of {ODOMETRY} are unusable, their frames skipped: "
                        f"{name_list(bad_rows)}")
    if repairs.warning():
        warnings.append(f"{path / ODOMETRY}: {repairs.warning()}")
    if not usable:
        raise CaptureError(f"{path / ODOMETRY} has no usable camera pose ({'; '.join(warnings) or 'no rows'}): "
                           "copy the recording folder from the phone again.")

    if all(time is not None for _, time, _ in usable):
        times = [time for _, time, _ in usable]
    else:  # an odometry file without timestamps: the video's rate places the frames in time
        fps = _video_fps(path / VIDEO)
        times = [number / fps for number, _, _ in usable]
    selected = [usable[i] for i in frames_at_rate(times, options.fps)]
    folder, done = _extracted_frames(path, [number for number, _, _ in selected], options, progress, cancel)
    warnings += done["warnings"]

    video_frames = done["video_frames"]
    row_numbers = {number for number, _, _, _ in rows}  # unusable rows too: they were warned about above
    past_end = sorted(number for number in row_numbers if number >= video_frames)
    if past_end:
        warnings.append(f"{VIDEO} holds {video_frames} frames but {ODOMETRY} has poses up to frame {past_end[-1]:06d}: "
                        f"the {len(past_end)} pose(s) past the video's end are unused (was the recording cut short?)")
    without_pose = video_frames - sum(1 for number in row_numbers if number < video_frames)
    if without_pose:
        warnings.append(f"{ODOMETRY} has poses for {video_frames - without_pose} of the {video_frames} frames of "
                        f"{VIDEO}: the {without_pose} frame(s) without a row are not used")

    pose_of = {number: pose for number, _, pose in usable}
    entries: list[tuple[Path, np.ndarray, Optional[SensorDepth]]] = []
    no_depth = []
    for number, name in done["frames"]:
        depth = path / "depth" / f"{number:06d}.png"
        confidence = path / "confidence" / f"{number:06d}.png"
        sensor = None
        if depth.is_file():
            sensor = SensorDepth(depth, "png_mm", confidence if confidence.is_file() else None)
        else:
            no_depth.append(name)
        entries.append((folder / name, pose_of[number], sensor))
    if no_depth and len(no_depth) < len(entries):  # a recording without any depth is no problem
        warnings.append(f"{len(no_depth)} frame(s) have no depth/NNNNNN.png, used without depth: {name_list(no_depth)}")

    skipped = SkippedPhotos()
    infos = inspect_images([photo for photo, _, _ in entries], skipped, verify=options.verify_images,
                           progress=progress, cancel=cancel)
    sizes = [info.size for info in infos if info is not None]
    if sizes:
        _check_principal_point(K, sizes[0], path)
    frames = [Frame(image_path=photo, width=info.width, height=info.height, K=K.copy(), pose=pose, sensor_depth=sensor)
              for (photo, pose, sensor), info in zip(entries, infos) if info is not None]
    capture = finish_phone_capture(path, "strayscanner", APP, frames, [info for info in infos if info is not None], path,
                                   options, warnings, skipped, what="posed frame")
    capture.notes.append(f"{len(done['frames'])} of the {video_frames} frames of {VIDEO} (about {options.fps:g} per "
                         f"second) extracted into {folder}")
    return capture
