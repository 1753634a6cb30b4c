"""Writers for posed captures: the ScanNet layout and a COLMAP text model.

Both are read back by this package's loaders (`scannet.py`, `colmap.py`), so a capture posed by
structure from motion is saved once and then loads like any other:

    out/color/<stem>.jpg|png           the photos, copied unchanged (names and order kept)
    out/pose/<stem>.txt                camera-to-world 4x4, OpenCV camera axes
    out/intrinsic/intrinsic_color.txt  K as a 4x4 matrix (ScanNet's SensReader convention)
    out/colmap/cameras.txt, images.txt, points3D.txt
                                       the same cameras as a COLMAP text model; image names are the
                                       file names in color/ (load it with images_dir=out/color)

Depth images are not written: captures posed by SfM have none.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from .images import load_image
from .model import Capture, Frame

SCANNET_FOLDERS = ("color", "pose", "intrinsic")
_COPY_SUFFIXES = {".jpg": ".jpg", ".jpeg": ".jpg", ".png": ".png"}


def rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> unit quaternion (4,) (w, x, y, z) with w >= 0, as COLMAP writes it.

    Shepperd's method: pivot on the largest of w, x, y, z so no division is by a small number.
    """
    R = np.asarray(R, dtype=np.float64)
    trace = np.trace(R)
    candidates = np.array([trace, R[0, 0], R[1, 1], R[2, 2]])
    i = int(np.argmax(candidates))
    if i == 0:
        w = 0.5 * np.sqrt(1.0 + trace)
        q = np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])
    elif i == 1:
        x = 0.5 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([(R[2, 1] - R[1, 2]) / (4 * x), x, (R[0, 1] + R[1, 0]) / (4 * x), (R[0, 2] + R[2, 0]) / (4 * x)])
    elif i == 2:
        y = 0.5 * np.sqrt(1.0 - R[0, 0] + R[1, 1] - R[2, 2])
        q = np.array([(R[0, 2] - R[2, 0]) / (4 * y), (R[0, 1] + R[1, 0]) / (4 * y), y, (R[1, 2] + R[2, 1]) / (4 * y)])
    else:
        z = 0.5 * np.sqrt(1.0 - R[0, 0] - R[1, 1] + R[2, 2])
        q = np.array([(R[1, 0] - R[0, 1]) / (4 * z), (R[0, 2] + R[2, 0]) / (4 * z), (R[1, 2] + R[2, 1]) / (4 * z), z])
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def _matrix_text(matrix: np.ndarray) -> str:
    # %.17g round-trips float64 exactly.
    return "\n".join(" ".join(f"{v:.17g}" for v in row) for row in matrix) + "\n"


def _output_names(frames: list[Frame]) -> list[str]:
    """color/ file names: the photos' own stems, index-prefixed only when two stems collide."""
    suffixes = [_COPY_SUFFIXES.get(f.image_path.suffix.lower(), ".jpg") for f in frames]
    stems = [f.image_path.stem for f in frames]
    if len(set(stems)) < len(stems):
        stems = [f"{i:05d}_{stem}" for i, stem in enumerate(stems)]
    return [stem + suffix for stem, suffix in zip(stems, suffixes)]


def _shared_camera(frames: list[Frame], where: Path) -> tuple[np.ndarray, int, int]:
    """The one (K, width, height) of all frames; ScanNet's layout has a single colour camera."""
    first = frames[0]
    if first.K is None:
        raise CaptureError(f"frame {first.name} has no intrinsics: cannot write {where}")
    for frame in frames[1:]:
        if (frame.width, frame.height) != (first.width, first.height) or frame.K is None or not np.allclose(
            frame.K, first.K, rtol=1e-9, atol=1e-9
        ):
            raise CaptureError(
                f"frames {first.name} and {frame.name} have different intrinsics or sizes, but the ScanNet "
                f"layout in {where} holds one camera: write a COLMAP model instead"
            )
    return np.asarray(first.K, dtype=np.float64), first.width, first.height


def _prepare_folder(out_dir: Path, frames: list[Frame], overwrite: bool) -> None:
    """Make sure color/, pose/ and intrinsic/ can be written without mixing with an older capture."""
    out = out_dir.resolve()
    for frame in frames:
        if out in frame.image_path.resolve().parents:
            raise CaptureError(
                f"photo {frame.image_path} lies inside the output folder {out_dir}: choose another output folder"
            )
    existing = [out_dir / name for name in SCANNET_FOLDERS if (out_dir / name).is_dir() and any((out_dir / name).iterdir())]
    if existing and not overwrite:
        raise CaptureError(
            f"{out_dir} already holds a capture ({', '.join(p.name for p in existing)}/ not empty): "
            "choose an empty folder or allow overwriting (CLI: --overwrite)"
        )
    for folder in existing:
        shutil.rmtree(folder)
    for name in SCANNET_FOLDERS:
        (out_dir / name).mkdir(parents=True, exist_ok=True)


def write_scannet(capture: Capture, out_dir: Path | str, overwrite: bool = False) -> Capture:
    """Write the posed frames of `capture` in the ScanNet layout; return the Capture of that folder.

    Frames without a pose are left out (ScanNet's layout has no way to say "unknown pose").
    JPEG and PNG photos are copied byte for byte (EXIF orientation included, which the loader
    applies again, so K stays valid); other images are re-encoded as JPEG (quality 95) after
    applying their orientation. Raises CaptureError when there is nothing to write, the frames
    do not share one camera, or `out_dir` already holds a capture and `overwrite` is False.
    """
    out_dir = Path(out_dir)
    frames = capture.posed_frames
    if not frames:
        raise CaptureError(f"no frame of {capture.root} has a camera pose: nothing to write to {out_dir}")
    K, width, height = _shared_camera(frames, out_dir)
    _prepare_folder(out_dir, frames, overwrite)

    written: list[Frame] = []
    for frame, name in zip(frames, _output_names(frames)):
        target = out_dir / "color" / name
        if frame.image_path.suffix.lower() in _COPY_SUFFIXES:
            shutil.copyfile(frame.image_path, target)
        else:
            import cv2  # defers cv2 (OpenCV) off the light paths
            ok, encoded = cv2.imencode(".jpg", cv2.cvtColor(load_image(frame.image_path), cv2.COLOR_RGB2BGR),
                                       [cv2.IMWRITE_JPEG_QUALITY, 95])
            if not ok:
                raise CaptureError(f"could not encode {frame.image_path} as JPEG for {target}")
            encoded.tofile(str(target))
        assert frame.pose is not None
        (out_dir / "pose" / f"{target.stem}.txt").write_text(_matrix_text(frame.pose))
        written.append(replace(frame, image_path=target, depth_path=None))

    K4 = np.eye(4)
    K4[:3, :3] = K
    (out_dir / "intrinsic" / "intrinsic_color.txt").write_text(_matrix_text(K4))
    return Capture(root=out_dir, format="scannet", frames=written, metric=capture.metric)


def write_colmap_text(
    capture: Capture,
    out_dir: Path | str,
    points: Optional[np.ndarray] = None,
    colors: Optional[np.ndarray] = None,
) -> None:
    """Write the posed frames as a COLMAP text model (cameras.txt, images.txt, points3D.txt).

    One PINHOLE camera per distinct (K, width, height). Image names are the photos' file names.
    points: (N, 3) world points, colors: (N, 3) uint8 RGB (grey when None); their tracks are left
    empty, so they are for display, not for re-running bundle adjustment.
    """
    out_dir = Path(out_dir)
    frames = capture.posed_frames
    if not frames:
        raise CaptureError(f"no frame of {capture.root} has a camera pose: nothing to write to {out_dir}")
    out_dir.mkdir(parents=True, exist_ok=True)

    cameras: list[tuple[np.ndarray, int, int]] = []
    camera_of: list[int] = []
    for frame in frames:
        if frame.K is None:
            raise CaptureError(f"frame {frame.name} has no intrinsics: cannot write {out_dir}")
        for camera_id, (K, w, h) in enumerate(cameras, start=1):
            if (w, h) == (frame.width, frame.height) and np.allclose(K, frame.K, rtol=1e-9, atol=1e-9):
                camera_of.append(camera_id)
                break
        else:
            cameras.append((np.asarray(frame.K, dtype=np.float64), frame.width, frame.height))
            camera_of.append(len(cameras))

    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    for camera_id, (K, w, h) in enumerate(cameras, start=1):
        lines.append(f"{camera_id} PINHOLE {w} {h} {K[0, 0]!r} {K[1, 1]!r} {K[0, 2]!r} {K[1, 2]!r}")
    (out_dir / "cameras.txt").write_text("\n".join(lines) + "\n")

    lines = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
    ]
    for image_id, (frame, camera_id) in enumerate(zip(frames, camera_of), start=1):
        assert frame.pose is not None
        # COLMAP stores world-to-camera: R = R_c^T, t = -R_c^T c.
        rotation = frame.pose[:3, :3].T
        translation = -rotation @ frame.pose[:3, 3]
        q = rotation_to_quaternion(rotation)
        numbers = " ".join(f"{v:.17g}" for v in (*q, *translation))
        lines += [f"{image_id} {numbers} {camera_id} {frame.image_path.name}", ""]
    (out_dir / "images.txt").write_text("\n".join(lines) + "\n")

    lines = ["# 3D point list with one line of data per point:", "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[]"]
    if points is not None:
        xyz = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        rgb = np.full((len(xyz), 3), 128, np.uint8) if colors is None else np.asarray(colors, np.uint8).reshape(-1, 3)
        if len(rgb) != len(xyz):
            raise ValueError(f"{len(xyz)} points but {len(rgb)} colours")
        for point_id, (p, c) in enumerate(zip(xyz, rgb), start=1):
            lines.append(f"{point_id} {p[0]:.9g} {p[1]:.9g} {p[2]:.9g} {c[0]} {c[1]} {c[2]} 0")
    (out_dir / "points3D.txt").write_text("\n".join(lines) + "\n")
