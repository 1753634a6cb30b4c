"""Loader for a video file (format "video"): frames sampled at a fixed rate, blurry ones dropped.

Frames are taken every 1/`fps` seconds of video (default 2 per second; the first frame at or after
each sample time) and written as JPEG quality 95 into the cache (see `cache.py`; by default
`<user cache>/vortx/<folder>-<hash>/video-<name>-<fps>fps/`). Handheld video has motion-blurred frames
that poison feature matching and the network's features, so each frame's sharpness is measured as
the variance of its Laplacian (on a grey copy at most 640 px wide, so the measure does not depend
on the video's resolution), and frames under `blur_fraction` (default 0.5) of the median
sharpness are dropped. A fixed fraction of the median, rather than "the blurriest 20 %", keeps
every frame of a steady video and drops more of a shaky one. The result is an unposed capture like
a photo folder (K unknown: videos carry no usable focal length).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn, check, report
from .cache import cache_folder, read_manifest, reset_folder, source_stamp, write_manifest
from .folder import capture_from_photos
from .model import Capture
from .naming import name_list
from .options import LoadOptions

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".m4v", ".mkv")
_SHARPNESS_WIDTH = 640
_FALLBACK_FPS = 30.0


def is_video_file(path: Path) -> bool:
    return path.suffix.lower() in VIDEO_SUFFIXES and path.is_file()


def sharpness(rgb_or_bgr: np.ndarray) -> float:
    """Variance of the Laplacian of a grey copy at most 640 px wide (higher = sharper)."""
    import cv2  # defers cv2 (OpenCV) off the light paths
    grey = cv2.cvtColor(rgb_or_bgr, cv2.COLOR_BGR2GRAY) if rgb_or_bgr.ndim == 3 else rgb_or_bgr
    if grey.shape[1] > _SHARPNESS_WIDTH:
        height = max(1, round(grey.shape[0] * _SHARPNESS_WIDTH / grey.shape[1]))
        grey = cv2.resize(grey, (_SHARPNESS_WIDTH, height), interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def blurry_frames(scores: list[float], blur_fraction: float) -> list[int]:
    """Indices of frames whose sharpness is below `blur_fraction` x the median sharpness."""
    if blur_fraction <= 0 or not scores:
        return []
    threshold = blur_fraction * float(np.median(scores))
    return [i for i, score in enumerate(scores) if score < threshold]


def _extract(video: Path, folder: Path, fps: float, progress: Optional[ProgressFn],
             cancel: Optional[CancelToken]) -> tuple[list[str], list[float], list[str]]:
    """Writes the sampled frames; returns their file names, sharpness and warnings."""
    import cv2  # defers cv2 (OpenCV) off the light paths
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise CaptureError(f"cannot open video {video}: the file is damaged or its codec is not supported by "
                           "OpenCV. Convert it to H.264 MP4, or extract photos from it yourself.")
    warnings = []
    try:
        native_fps = capture.get(cv2.CAP_PROP_FPS)
        if not (math.isfinite(native_fps) and native_fps > 0):
            warnings.append(f"{video.name} does not state its frame rate; assumed {_FALLBACK_FPS:g} fps")
            native_fps = _FALLBACK_FPS
        total = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) or 0
        step = 1.0 / min(fps, native_fps)
        names, scores = [], []
        index, next_time = 0, 0.0
        while True:
            check(cancel)
            if not capture.grab():  # grab without converting frames that are not kept
                break
            time = index / native_fps
            if time + 1e-6 >= next_time:
                ok, bgr = capture.retrieve()
                if ok and bgr is not None:
                    name = f"{video.stem}_{index:06d}.jpg"
                    scores.append(write_frame(bgr, folder / name, video, index))
                    names.append(name)
                next_time += step
                while next_time <= time:  # keep the schedule when frames are missing
                    next_time += step
            index += 1
            report(progress, "extracting video frames", index, max(total, index))
    finally:
        capture.release()
    if not names:
        raise CaptureError(f"no frame could be read from video {video}: the file is damaged or its codec is not "
                           "supported by OpenCV. Convert it to H.264 MP4.")
    return names, scores, warnings


def write_frame(bgr: np.ndarray, target: Path, video: Path, index: int) -> float:
    """Writes one decoded video frame (h, w, 3) BGR as a JPEG (quality 95) to `target`; returns its
    sharpness, for `blurry_frames`. CaptureError naming the video when it cannot be encoded."""
    import cv2  # defers cv2 (OpenCV) off the light paths

    ok, encoded = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not ok:
        raise CaptureError(f"could not encode frame {index} of {video} as JPEG.")
    encoded.tofile(str(target))
    return sharpness(bgr)


def load_video(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
               cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "video") of frames extracted from the video file `path`."""
    folder = cache_folder(path.parent, f"video-{path.stem}-{options.fps:g}fps", options.cache_dir)
    key = {"version": 1, "source": source_stamp([path]), "fps": options.fps, "blur_fraction": options.blur_fraction}
    done = read_manifest(folder, key)
    if done is None:
        reset_folder(folder)
        names, scores, warnings = _extract(path, folder, options.fps, progress, cancel)
        dropped = blurry_frames(scores, options.blur_fraction)
        for i in dropped:
            (folder / names[i]).unlink()
        if dropped:
            warnings.append(f"{len(dropped)} of {len(names)} extracted frames dropped as blurry (sharpness under "
                            f"{options.blur_fraction:g} x the median): {name_list([names[i] for i in dropped])}")
        dropped_set = set(dropped)
        kept = [name for i, name in enumerate(names) if i not in dropped_set]
        done = {"files": kept, "warnings": warnings}
        write_manifest(folder, key, done)
    capture = capture_from_photos([folder / name for name in done["files"]], root=path, format="video", where=path,
                                  options=options, warnings=done["warnings"], progress=progress, cancel=cancel)
    capture.notes.append(f"frames extracted from {path.name} at {options.fps:g} per second into {folder}")
    return capture
