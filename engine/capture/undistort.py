"""Undistorting photos of a lens with radial-tangential distortion into pinhole images.

The network and TSDF fusion assume a pinhole camera, so captures whose intrinsics carry distortion
(COLMAP SIMPLE_RADIAL/RADIAL/OPENCV, transforms.json k1 k2 p1 p2 [k3]) are resampled once with
OpenCV into a cache folder (see `cache.py`; by default
`<user cache>/vortx/<capture>-<hash>/undistorted-<hash>/`) and the capture then points at those
files with a pinhole K.

The new K comes from `cv2.getOptimalNewCameraMatrix(alpha=0)` at the same image size: every output
pixel sees the scene (no black border that the network would take for a dark wall), so the focal
length changes slightly and a little field of view near the borders is given up. The distortion
model is OpenCV's (identical to COLMAP's for these models).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn, check, report
from .cache import cache_folder, read_manifest, reset_folder, source_stamp, write_manifest
from .images import load_image
from .model import Capture
from .naming import name_list
from .options import LoadOptions

# OpenCV places pixel centres at integer coordinates, COLMAP (and this engine) at +0.5.
_HALF_PIXEL = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])


def has_distortion(dist: np.ndarray) -> bool:
    """True when any coefficient is non-zero (exporters write exact zeros for pinhole cameras)."""
    return bool(np.any(np.abs(np.asarray(dist, dtype=np.float64)) > 1e-12))


def undistorted_intrinsics(K: np.ndarray, dist: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Pinhole K (3, 3) of the undistorted image of `size` (width, height); K, dist as in the capture."""
    K_cv = _HALF_PIXEL @ K
    import cv2  # defers cv2 (OpenCV) off the light paths
    new_K_cv, _ = cv2.getOptimalNewCameraMatrix(K_cv, _opencv_coefficients(dist), size, 0.0, size)
    return np.linalg.inv(_HALF_PIXEL) @ new_K_cv


def _opencv_coefficients(dist: np.ndarray) -> np.ndarray:
    """(k1, k2, p1, p2[, k3]) as float64; OpenCV accepts 4 or 5 of them."""
    coefficients = np.asarray(dist, dtype=np.float64).ravel()
    if coefficients.size not in (4, 5):
        raise ValueError(f"expected k1 k2 p1 p2 [k3], got {coefficients.size} coefficients")
    return coefficients


def undistort_images(sources: list[Path], K: np.ndarray, dist: np.ndarray, size: tuple[int, int],
                     capture_folder: Path, cache_dir: Optional[Path] = None,
                     progress: Optional[ProgressFn] = None,
                     cancel: Optional[CancelToken] = None) -> tuple[list[Path], np.ndarray]:
    """Undistort `sources` (all taken with one camera: K (3, 3), dist (4,) or (5,), size (W, H)).

    Returns the undistorted files (same order) and their pinhole K (3, 3). Reuses a finished cache
    folder made from the same files and parameters.
    """
    dist = _opencv_coefficients(dist)
    parameters = {"K": np.asarray(K, dtype=np.float64).round(9).tolist(), "dist": dist.round(12).tolist(),
                  "size": list(size)}
    tag = hashlib.sha1(json.dumps(parameters).encode()).hexdigest()[:10]
    folder = cache_folder(capture_folder, f"undistorted-{tag}", cache_dir)
    key = {"version": 1, **parameters, "sources": source_stamp(sources)}
    done = read_manifest(folder, key)
    if done is not None:
        return [folder / name for name in done["files"]], np.array(done["K"], dtype=np.float64)

    reset_folder(folder)
    new_K = undistorted_intrinsics(K, dist, size)
    import cv2  # defers cv2 (OpenCV) off the light paths
    map_x, map_y = cv2.initUndistortRectifyMap(_HALF_PIXEL @ K, dist, None, _HALF_PIXEL @ new_K, size,
                                               cv2.CV_16SC2)
    # PNG stays lossless; photos are re-encoded as JPEG quality 95 (visually lossless, 10x smaller).
    names = [source.stem + (".png" if source.suffix.lower() == ".png" else ".jpg") for source in sources]
    if len(set(names)) < len(names):  # COLMAP names may repeat across sub-folders (cam1/0001.jpg)
        names = [f"{i:05d}_{name}" for i, name in enumerate(names)]
    outputs = []
    for i, (source, name) in enumerate(zip(sources, names)):
        check(cancel)
        report(progress, "undistorting photos", i, len(sources))
        rgb = load_image(source)
        if (rgb.shape[1], rgb.shape[0]) != tuple(size):
            raise CaptureError(f"image {source} is {rgb.shape[1]} x {rgb.shape[0]} but its camera is "
                               f"{size[0]} x {size[1]}: use the images the camera model was made for.")
        undistorted = cv2.remap(rgb, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        target = folder / name
        params = [] if target.suffix == ".png" else [cv2.IMWRITE_JPEG_QUALITY, 95]
        ok, encoded = cv2.imencode(target.suffix, cv2.cvtColor(undistorted, cv2.COLOR_RGB2BGR), params)
        if not ok:
            raise CaptureError(f"could not encode the undistorted copy of {source} into {target}.")
        encoded.tofile(str(target))  # tofile, not imwrite: imwrite fails on non-ASCII paths on Windows
        outputs.append(target)
    report(progress, "undistorting photos", len(sources), len(sources))
    write_manifest(folder, key, {"files": [p.name for p in outputs], "K": new_K.tolist()})
    return outputs, new_K


def undistort_capture(capture: Capture, distortion: dict[Path, np.ndarray], options: LoadOptions,
                      progress: Optional[ProgressFn] = None, cancel: Optional[CancelToken] = None) -> Capture:
    """The capture with each distorted frame replaced by its undistorted copy and pinhole K.

    `distortion` maps a frame's image path to its coefficients (k1, k2, p1, p2[, k3]); frames with
    all-zero or no coefficients are kept as they are. Frames sharing K and coefficients are
    undistorted together (one remap table). With `options.undistort` False the photos are kept,
    their K used as if pinhole, and a warning says so.
    """
    groups: dict[tuple[bytes, bytes], list[int]] = {}
    for index, frame in enumerate(capture.frames):
        dist = distortion.get(frame.image_path)
        if dist is not None and frame.K is not None and has_distortion(dist):
            key = (np.asarray(frame.K, dtype=np.float64).tobytes(), np.asarray(dist, dtype=np.float64).tobytes())
            groups.setdefault(key, []).append(index)
    if not groups:
        return capture
    count = sum(len(indices) for indices in groups.values())
    if not options.undistort:
        return capture.with_frames(capture.frames, warnings=capture.warnings + [
            f"{count} photo(s) have lens distortion but undistort=False: they are used as pinhole images, "
            "so geometry near the image borders will be slightly off"])
    frames = list(capture.frames)
    capture_folder = capture.root if capture.root.is_dir() else capture.root.parent
    folders: list[Path] = []
    for indices in groups.values():
        first = frames[indices[0]]
        sources = [frames[i].image_path for i in indices]
        outputs, new_K = undistort_images(sources, first.K, distortion[first.image_path], (first.width, first.height),
                                          capture_folder, options.cache_dir, progress, cancel)
        for i, output in zip(indices, outputs):
            frames[i] = replace(frames[i], image_path=output, K=new_K.copy())
        folders.append(outputs[0].parent)
    return capture.with_frames(frames, notes=capture.notes + [
        f"{count} photo(s) undistorted (lens distortion removed, pinhole K) into {name_list(map(str, folders))}"])
