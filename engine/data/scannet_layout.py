"""Writing a rendered room in the ScanNet export layout (what `engine.capture` reads back).

    color/000000.jpg         RGB photo
    depth/000000.png         uint16 depth in millimetres, 0 = no depth (same stem as the photo)
    depth_float/000000.npy   float32 planar depth in metres (exact; the PNG is rounded to 1 mm)
    pose/000000.txt          camera-to-world 4x4, OpenCV camera axes, metres, world Z up
    intrinsic/intrinsic_color.txt, intrinsic_depth.txt   4x4 (K in the top-left 3x3)
    intrinsic/extrinsic_color.txt, extrinsic_depth.txt   4x4 identity (colour and depth share a camera)

A "real" room (`synth --realism real`, engine.data.degrade) adds, for scoring and comparison:

    pose_true/000000.txt     the exact pose the frame was rendered from (pose/ then holds it with a
                             per-frame error of 0.5-2 deg and 1-3 cm, what a method is given)
    color_clean/000000.png   the render before the photo degradations (lossless)
    degradations.json        what was done to each photo (exposure, white balance, blur, JPEG quality)

Depth maps, mesh_gt.ply and the TSDF are always those of the true poses.

K follows the engine's convention (pixel (0, 0) covers [0, 1)^2); colour and depth have the same size.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

COLOR_DIR, DEPTH_DIR, DEPTH_FLOAT_DIR, POSE_DIR, INTRINSIC_DIR = "color", "depth", "depth_float", "pose", "intrinsic"
TRUE_POSE_DIR, CLEAN_COLOR_DIR = "pose_true", "color_clean"
MAX_DEPTH_MM = 65535


def frame_stem(index: int) -> str:
    return f"{index:06d}"


def color_path(root: Path, index: int) -> Path:
    return root / COLOR_DIR / f"{frame_stem(index)}.jpg"


def clean_color_path(root: Path, index: int) -> Path:
    return root / CLEAN_COLOR_DIR / f"{frame_stem(index)}.png"


def pose_path(root: Path, index: int, folder: str = POSE_DIR) -> Path:
    return root / folder / f"{frame_stem(index)}.txt"


def depth_float_path(root: Path, index: int) -> Path:
    return root / DEPTH_FLOAT_DIR / f"{frame_stem(index)}.npy"


def write_intrinsics(root: Path, K: np.ndarray) -> None:
    folder = root / INTRINSIC_DIR
    folder.mkdir(parents=True, exist_ok=True)
    K4 = np.eye(4)
    K4[:3, :3] = K
    for name in ("intrinsic_color.txt", "intrinsic_depth.txt"):
        np.savetxt(folder / name, K4, fmt="%.6f")
    for name in ("extrinsic_color.txt", "extrinsic_depth.txt"):
        np.savetxt(folder / name, np.eye(4), fmt="%.6f")


def write_depth(root: Path, index: int, depth: np.ndarray) -> None:
    """Both depth files of a frame: depth (H, W) float32 metres, 0 = none. Atomic per file (tmp + rename)."""
    stem = frame_stem(index)
    mm = np.round(depth.astype(np.float64) * 1000.0)
    mm[(mm > MAX_DEPTH_MM) | (mm < 0)] = 0
    png = root / DEPTH_DIR / f"{stem}.png"
    png.parent.mkdir(parents=True, exist_ok=True)
    tmp = png.with_name(f".{stem}.tmp.png")
    if not cv2.imwrite(str(tmp), mm.astype(np.uint16)):
        raise OSError(f"could not write {png}")
    os.replace(tmp, png)
    npy = depth_float_path(root, index)
    npy.parent.mkdir(parents=True, exist_ok=True)
    tmp = npy.with_name(f".{stem}.tmp.npy")
    np.save(tmp, depth.astype(np.float32))
    os.replace(tmp, npy)


def write_pose(root: Path, index: int, cam_to_world: np.ndarray, folder: str = POSE_DIR) -> None:
    """The pose/ file is written last for a frame: its presence marks the frame complete (resume
    relies on it). folder=TRUE_POSE_DIR writes a "real" room's true pose."""
    path = pose_path(root, index, folder)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{frame_stem(index)}.tmp.txt")
    np.savetxt(tmp, np.asarray(cam_to_world, np.float64), fmt="%.9f")
    os.replace(tmp, path)


def frame_complete(root: Path, index: int) -> bool:
    stem = frame_stem(index)
    return all(p.is_file() for p in (color_path(root, index), root / DEPTH_DIR / f"{stem}.png",
                                     depth_float_path(root, index), pose_path(root, index)))


def read_depth_float(root: Path, index: int) -> np.ndarray:
    return np.load(depth_float_path(root, index))

