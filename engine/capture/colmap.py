"""Loader for a COLMAP sparse reconstruction (format "colmap").

Where the model is looked for, in `path`: `sparse/<n>/` (when COLMAP made several models, the one
with the most registered images is used and a warning names the others), `sparse/`,
`colmap/sparse/<n>/` (nerfstudio's layout), or `path` itself. Photos are looked up by the model's
image names in `images_dir=` if given, else `images/` beside `sparse/` (or beside/in the model
folder), else the folder itself.

Camera models: SIMPLE_PINHOLE and PINHOLE are used as they are; SIMPLE_RADIAL, RADIAL and OPENCV
with non-zero distortion are undistorted into the cache (see `undistort.py`); any other model
(fisheye, FULL_OPENCV, ...) is refused with a message naming it.

COLMAP stores world-to-camera (qvec, tvec) in OpenCV camera axes; frames get camera-to-world.
The world frame is COLMAP's (arbitrary orientation and scale): `metric` is False unless the
`metric=True` option says the model was scaled to metres; gravity alignment is the poses stage's job.
Registered images whose photo is missing or whose pose is not finite are skipped with a warning;
quaternions that are not unit length (rounded by the writer) are normalised when within
`geometry.ROTATION_TOLERANCE`, with one warning when they were off by more than rounding.
The model's sparse points (points3D, with their colours) come along as `Capture.points`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn
from .checks import SkippedPhotos, finish_capture, inspect_images
from .colmap_model import ColmapCamera, ColmapModel, model_kind, read_model, read_points
from .colmap_model import ColmapImage
from .geometry import (ROTATION_TOLERANCE, PoseRepairs, camera_to_world_from_world_to_camera, fit_intrinsics, pinhole,
                       quaternion_deviation, quaternion_to_rotation)
from .images import UnusableImage, list_images
from .model import Capture, Frame
from .naming import name_list, natural_key
from .options import LoadOptions
from .undistort import undistort_capture

SUPPORTED_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")


def camera_intrinsics(camera: ColmapCamera) -> tuple[np.ndarray, np.ndarray]:
    """K (3, 3) and OpenCV distortion (k1, k2, p1, p2) of a supported COLMAP camera."""
    p = camera.params
    if camera.model == "SIMPLE_PINHOLE":
        return pinhole(p[0], p[0], p[1], p[2]), np.zeros(4)
    if camera.model == "PINHOLE":
        return pinhole(p[0], p[1], p[2], p[3]), np.zeros(4)
    if camera.model == "SIMPLE_RADIAL":
        return pinhole(p[0], p[0], p[1], p[2]), np.array([p[3], 0.0, 0.0, 0.0])
    if camera.model == "RADIAL":
        return pinhole(p[0], p[0], p[1], p[2]), np.array([p[3], p[4], 0.0, 0.0])
    if camera.model == "OPENCV":
        return pinhole(p[0], p[1], p[2], p[3]), np.array(p[4:8])
    raise ValueError(f"unsupported camera model {camera.model}")


def find_model_folders(path: Path) -> list[Path]:
    """Every folder under the usual places in `path` that holds a COLMAP model (may be empty)."""
    candidates: list[Path] = []
    for sparse in (path / "sparse", path / "colmap" / "sparse"):
        if sparse.is_dir():
            numbered = sorted((d for d in sparse.iterdir() if d.is_dir() and d.name.isdigit()),
                              key=lambda d: int(d.name))
            candidates += numbered + [sparse]
    candidates.append(path)
    return [folder for folder in candidates if model_kind(folder) is not None]


def _choose_model(path: Path) -> tuple[ColmapModel, list[str]]:
    folders = find_model_folders(path)
    if not folders:
        raise CaptureError(f"no COLMAP model in {path}: expected cameras.txt/images.txt or cameras.bin/images.bin "
                           "in sparse/0/, sparse/ or the folder itself.")
    models = [read_model(folder) for folder in folders]
    best = max(models, key=lambda m: len(m.images))  # max keeps the first on ties: sparse/0 first
    warnings = []
    others = [m for m in models if m is not best]
    if others:
        warnings.append(f"several COLMAP models found; using {best.folder} ({len(best.images)} images), ignoring "
                        + name_list([f"{m.folder} ({len(m.images)} images)" for m in others]))
    return best, warnings


def _images_folder(model: ColmapModel, path: Path, options: LoadOptions) -> Path:
    """The folder where the most of the model's image names exist (ties: the first candidate)."""
    if options.images_dir is not None:
        if not options.images_dir.is_dir():
            raise CaptureError(f"images folder {options.images_dir} does not exist: pass the folder holding the "
                               "photos of the COLMAP model.")
        return options.images_dir
    candidates = [path / "images", model.folder / "images", model.folder.parent / "images",
                  model.folder.parent.parent / "images", path, model.folder]
    candidates = list(dict.fromkeys(c for c in candidates if c.is_dir()))
    sample = [image.name for image in model.images[:50]]  # enough to tell the right folder
    if not sample:
        return candidates[0]
    hits = [sum((folder / name).is_file() for name in sample) for folder in candidates]
    best = int(np.argmax(hits))
    if hits[best] == 0:
        raise CaptureError(f"none of the photos named in {model.folder} (e.g. {sample[0]}) is in "
                           f"{name_list([str(c) for c in candidates])}: put them in {path / 'images'} or pass "
                           "--images-dir FOLDER (engine reconstruct, engine poses and engine info take it).")
    return candidates[best]


def _refuse_unsupported(model: ColmapModel, camera_ids: set[int]) -> None:
    for camera_id in sorted(camera_ids):
        camera = model.cameras.get(camera_id)
        if camera is None:
            raise CaptureError(f"{model.folder}: an image refers to camera {camera_id}, which "
                               f"{model.cameras_file.name} does not define: the model is incomplete; re-export it.")
        if camera.model not in SUPPORTED_MODELS:
            raise CaptureError(f"{model.cameras_file}: camera {camera_id} uses the {camera.model} camera model, which "
                               f"is not supported (supported: {', '.join(SUPPORTED_MODELS)}). Undistort the images "
                               "with COLMAP (`colmap image_undistorter`, which writes a PINHOLE model) or "
                               "reconstruct again with camera model OPENCV or PINHOLE.")


def _camera_to_world(image: ColmapImage, repairs: PoseRepairs) -> np.ndarray:
    """(4, 4) camera-to-world of a registered image; ValueError saying why its pose is unusable."""
    if not (np.all(np.isfinite(image.qvec)) and np.all(np.isfinite(image.tvec))):
        raise ValueError("non-finite values (inf/NaN)")
    deviation = quaternion_deviation(image.qvec)
    if deviation > ROTATION_TOLERANCE:
        length = float(np.linalg.norm(image.qvec))
        raise ValueError(f"its quaternion has length {length:.4g}, not 1: | |q|^2 - 1 | = {deviation:.2g}, more "
                         f"than the {ROTATION_TOLERANCE:g} tolerated")
    pose = camera_to_world_from_world_to_camera(quaternion_to_rotation(image.qvec), image.tvec)
    return repairs.make_rigid(pose, image.name, deviation)


def load_colmap(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
                cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "colmap") of the registered images of the COLMAP model in `path`."""
    model, warnings = _choose_model(path)
    _refuse_unsupported(model, {image.camera_id for image in model.images})
    images_folder = _images_folder(model, path, options)

    missing, bad_poses, entries = [], [], []
    bad_pose_names: set[str] = set()  # registered, so not to be reported again as "not registered"
    repairs = PoseRepairs()
    for image in sorted(model.images, key=lambda im: natural_key(im.name)):
        image_path = images_folder / image.name
        try:
            pose = _camera_to_world(image, repairs)
        except ValueError as error:
            bad_poses.append(f"{image.name} ({error})")
            bad_pose_names.add(image.name)
            continue
        if image_path.is_file():
            entries.append((image, image_path, pose))
        else:
            missing.append(image.name)
    if bad_poses:
        warnings.append(f"{len(bad_poses)} image(s) in {model.folder} skipped for an unusable pose: "
                        f"{name_list(bad_poses)}")
    if repairs.warning():
        warnings.append(f"{model.images_file}: {repairs.warning()}")
    if missing:
        warnings.append(f"{len(missing)} image(s) of the COLMAP model are missing from {images_folder}, skipped: "
                        f"{name_list(missing)}")
    used = {image.name for image, _, _ in entries} | set(missing) | bad_pose_names
    unregistered = [p.name for p in list_images(images_folder) if p.name not in used
                    and p.relative_to(images_folder).as_posix() not in used]
    if unregistered and entries:
        warnings.append(f"{len(unregistered)} photo(s) in {images_folder} are not registered in the COLMAP model "
                        f"and are left out: {name_list(unregistered)}")

    skipped = SkippedPhotos()
    infos = inspect_images([p for _, p, _ in entries], skipped, verify=options.verify_images, progress=progress,
                           cancel=cancel)
    frames, usable_infos, distortion = [], [], {}
    fit_warnings: dict[int, str] = {}
    for (image, image_path, pose), info in zip(entries, infos):
        if info is None:
            continue
        camera = model.cameras[image.camera_id]
        K, dist = camera_intrinsics(camera)
        try:
            K, fit_warning = fit_intrinsics(K, (camera.width, camera.height), info.size, image_path,
                                            f"{model.cameras_file} (camera {camera.camera_id})")
        except UnusableImage as error:  # another aspect ratio than its camera
            skipped.add(error)
            continue
        if fit_warning:
            fit_warnings.setdefault(camera.camera_id, fit_warning)
        frames.append(Frame(image_path=image_path, width=info.width, height=info.height, K=K, pose=pose))
        usable_infos.append(info)
        distortion[image_path] = dist
    warnings += fit_warnings.values()
    metric = bool(options.metric)
    capture = finish_capture(path, "colmap", frames, usable_infos, model.folder, metric, warnings, skipped,
                             what="posed photo")
    capture = _with_model_points(capture, model)
    return undistort_capture(capture, distortion, options, progress, cancel)


def _with_model_points(capture: Capture, model: ColmapModel) -> Capture:
    """`capture` with the model's sparse points (points3D), when it has any. They are optional (the
    poses are what the capture needs), so an unreadable points file is a warning, not a failure."""
    try:
        points = read_points(model.folder, model.kind)
    except CaptureError as error:
        return capture.with_frames(capture.frames, warnings=capture.warnings + [f"sparse points left out: {error}"])
    if points is None or len(points.xyz) == 0:
        return capture
    finite = np.all(np.isfinite(points.xyz), axis=1)
    return capture.with_points(points.xyz[finite], points.rgb[finite])
