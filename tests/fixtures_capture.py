"""Helpers that write small synthetic captures on disk, for any test that needs one.

Everything here is written independently of `engine.capture` (own COLMAP writers, own quaternion
and distortion code) so loader tests compare against values computed another way.

Conventions match the engine: camera-to-world (4, 4) poses with OpenCV camera axes, K (3, 3) with
pixel (0, 0) covering [0, 1)^2, images uint8 (H, W, 3) RGB.

Typical use:
    poses = ring_poses(6)
    K = intrinsics(80.0, 64, 48)
    write_scannet(tmp_path / "scan", poses, K, (64, 48))
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Iterable, Optional, Sequence

import cv2
import numpy as np
from PIL import ExifTags, Image

from engine.geometry.cameras import look_along, look_at, project_points

# COLMAP camera model ids (src/colmap/sensor/models.h), for the binary writer.
COLMAP_MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4,
                    "OPENCV_FISHEYE": 5, "FULL_OPENCV": 6, "FISHEYE": 15}


# ---------------------------------------------------------------- images

def textured_image(width: int, height: int, seed: int = 0) -> np.ndarray:
    """(H, W, 3) uint8 RGB with detail at several scales (sharp, distinct per seed, JPEG-friendly)."""
    rng = np.random.default_rng(seed)
    image = np.zeros((height, width, 3), dtype=np.float32)
    for cell in (16, 4, 1):
        small = rng.random((max(1, height // cell) + 1, max(1, width // cell) + 1, 3)).astype(np.float32)
        image += cv2.resize(small, (width, height), interpolation=cv2.INTER_NEAREST) / 3.0
    return np.clip(image * 255.0, 0, 255).astype(np.uint8)


def write_image(path: Path, rgb: np.ndarray) -> Path:
    """Writes RGB as PNG or JPEG (quality 95) by suffix; creates the folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    params = [cv2.IMWRITE_JPEG_QUALITY, 95] if path.suffix.lower() in (".jpg", ".jpeg") else []
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params), path
    return path


def write_photo_folder(folder: Path, count: int, size: tuple[int, int] = (64, 48), suffix: str = ".png",
                       names: Optional[Sequence[str]] = None, seed: int = 0) -> list[Path]:
    """`count` distinct textured photos of `size` (W, H) named names[i] or frame<i><suffix>."""
    names = list(names) if names is not None else [f"frame{i}{suffix}" for i in range(count)]
    return [write_image(folder / name, textured_image(size[0], size[1], seed + i)) for i, name in enumerate(names)]


def write_exif_jpeg(path: Path, rgb: np.ndarray, orientation: Optional[int] = None,
                    focal_35mm: Optional[float] = None, focal_mm: Optional[float] = None,
                    focal_plane_x_resolution: Optional[float] = None, focal_plane_unit: Optional[int] = None) -> Path:
    """JPEG of the *stored* pixels `rgb` with the given EXIF tags (written with Pillow)."""
    exif = Image.Exif()
    if orientation is not None:
        exif[0x0112] = orientation
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    for tag, value in ((0xA405, focal_35mm), (0x920A, focal_mm), (0xA20E, focal_plane_x_resolution),
                       (0xA210, focal_plane_unit)):
        if value is not None:
            sub[tag] = value
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb).save(path, exif=exif, quality=95)
    return path


# ---------------------------------------------------------------- cameras

def intrinsics(focal: float, width: int, height: int, fy: Optional[float] = None) -> np.ndarray:
    return np.array([[focal, 0.0, width / 2.0], [0.0, fy or focal, height / 2.0], [0.0, 0.0, 1.0]])


def look_yaw_pitch(position: Sequence[float], yaw: float, pitch: float) -> np.ndarray:
    """Camera-to-world (4, 4), OpenCV axes, looking along yaw (about +Z) and pitch (up positive)."""
    return look_along(position, [np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])


def ring_poses(count: int, radius: float = 2.0, height: float = 1.5,
               target: Sequence[float] = (0.0, 0.0, 1.0)) -> list[np.ndarray]:
    """Cameras on a horizontal circle, all looking at `target` (a room-scan-like rig)."""
    angles = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
    return [look_at((radius * np.cos(a), radius * np.sin(a), height), target) for a in angles]


def project(K: np.ndarray, camera_to_world: np.ndarray, point: Sequence[float]) -> np.ndarray:
    """Pixel (2,) of a world point through a pinhole camera."""
    u, v, _ = project_points(np.asarray(point, dtype=np.float64)[None], K, camera_to_world)
    return np.array([u[0], v[0]])


def distort_normalized(xy: np.ndarray, k1: float = 0.0, k2: float = 0.0, p1: float = 0.0,
                       p2: float = 0.0) -> np.ndarray:
    """COLMAP/OpenCV radial-tangential distortion of normalised coordinates (N, 2)."""
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def blob_image(width: int, height: int, centres: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """White (H, W, 3) uint8 image with dark Gaussian blobs centred at pixel positions (N, 2)
    (engine convention: pixel (i, j) centre at (j + 0.5, i + 0.5))."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64) + 0.5
    darkness = np.zeros((height, width))
    for u, v in centres:
        darkness += np.exp(-((xs - u) ** 2 + (ys - v) ** 2) / (2.0 * sigma * sigma))
    grey = np.clip(255.0 * (1.0 - np.clip(darkness, 0, 1)), 0, 255).astype(np.uint8)
    return np.repeat(grey[:, :, None], 3, axis=2)


def blob_centroid(rgb: np.ndarray, near: Sequence[float], radius: int = 6) -> np.ndarray:
    """Darkness-weighted centroid (2,) in engine pixel coordinates of the blob near `near`."""
    u0, v0 = int(near[0]), int(near[1])
    window = 255.0 - rgb[max(0, v0 - radius):v0 + radius + 1, max(0, u0 - radius):u0 + radius + 1, 0].astype(np.float64)
    ys, xs = np.mgrid[max(0, v0 - radius):v0 + radius + 1, max(0, u0 - radius):u0 + radius + 1]
    ys, xs = ys[:window.shape[0], :window.shape[1]], xs[:window.shape[0], :window.shape[1]]
    total = window.sum()
    return np.array([(xs * window).sum() / total + 0.5, (ys * window).sum() / total + 0.5])


# ---------------------------------------------------------------- COLMAP

def rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(w, x, y, z) with w >= 0 of a rotation matrix (Shepperd's method)."""
    trace = np.trace(R)
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = np.zeros(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    return q if q[0] >= 0 else -q


def colmap_image_entry(image_id: int, camera_to_world: np.ndarray, camera_id: int, name: str) -> tuple:
    """(image_id, qvec, tvec, camera_id, name): the world-to-camera pose COLMAP stores."""
    world_to_camera = np.linalg.inv(camera_to_world)
    return (image_id, rotation_to_quaternion(world_to_camera[:3, :3]), world_to_camera[:3, 3], camera_id, name)


def write_colmap_text(folder: Path, cameras: Iterable[tuple], images: Iterable[tuple]) -> Path:
    """cameras: (camera_id, model, width, height, params); images: colmap_image_entry tuples."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:"]
    for cid, model, w, h, params in cameras:
        lines.append(f"{cid} {model} {w} {h} " + " ".join(repr(float(p)) for p in params))
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:"]
    for image_id, q, t, camera_id, name in images:
        lines.append(" ".join(str(v) for v in [image_id, *map(repr, map(float, q)), *map(repr, map(float, t)),
                                                camera_id, name]))
        lines.append("")  # no 2D points: COLMAP leaves the second line empty
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    (folder / "points3D.txt").write_text("# 3D point list\n")
    return folder


def write_colmap_binary(folder: Path, cameras: Iterable[tuple], images: Iterable[tuple],
                        points_per_image: int = 3) -> Path:
    """Same content as write_colmap_text, in COLMAP's binary layout (with a few dummy 2D points
    per image so readers must skip them)."""
    folder.mkdir(parents=True, exist_ok=True)
    cameras, images = list(cameras), list(images)
    data = struct.pack("<Q", len(cameras))
    for cid, model, w, h, params in cameras:
        data += struct.pack("<iiQQ", cid, COLMAP_MODEL_IDS[model], w, h) + struct.pack(f"<{len(params)}d", *params)
    (folder / "cameras.bin").write_bytes(data)
    data = struct.pack("<Q", len(images))
    for image_id, q, t, camera_id, name in images:
        data += struct.pack("<I4d3dI", image_id, *q, *t, camera_id) + name.encode() + b"\0"
        data += struct.pack("<Q", points_per_image)
        for k in range(points_per_image):
            data += struct.pack("<ddq", 1.5 * k, 2.5 * k, -1)
    (folder / "images.bin").write_bytes(data)
    (folder / "points3D.bin").write_bytes(struct.pack("<Q", 0))
    return folder


# ---------------------------------------------------------------- transforms.json, ScanNet, video

def write_transforms_json(path: Path, frames: Iterable[tuple[str, np.ndarray]], **top_level) -> Path:
    """transforms.json with `top_level` keys (fl_x, w, ...) and frames (file_path, OpenCV
    camera-to-world), stored in the NeRF/OpenGL camera convention as the real files are."""
    opengl = np.diag([1.0, -1.0, -1.0, 1.0])
    entries = []
    for file_path, pose in frames:
        entry = {"file_path": file_path}
        entry["transform_matrix"] = (np.asarray(pose) @ opengl).tolist() if pose is not None else None
        entries.append(entry)
    path.parent.mkdir(parents=True, exist_ok=True)
    # allow_nan: tests write NaN matrices on purpose (json writes them as NaN, as Python tools do)
    path.write_text(json.dumps({**top_level, "frames": entries}, indent=1, allow_nan=True))
    return path


def write_scannet(folder: Path, poses: Sequence[np.ndarray], K: np.ndarray, size: tuple[int, int],
                  depth: bool = True, seed: int = 0) -> list[Path]:
    """ScanNet export layout: color/<i>.jpg, pose/<i>.txt, intrinsic/intrinsic_color.txt (4x4),
    depth/<i>.png (16-bit mm, constant 1500) when `depth`. Returns the colour image paths."""
    colors = []
    for i, pose in enumerate(poses):
        colors.append(write_image(folder / "color" / f"{i}.jpg", textured_image(size[0], size[1], seed + i)))
        (folder / "pose").mkdir(parents=True, exist_ok=True)
        np.savetxt(folder / "pose" / f"{i}.txt", pose)
        if depth:
            (folder / "depth").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(folder / "depth" / f"{i}.png"), np.full((size[1], size[0]), 1500, np.uint16))
    (folder / "intrinsic").mkdir(parents=True, exist_ok=True)
    K4 = np.eye(4)
    K4[:3, :3] = K
    np.savetxt(folder / "intrinsic" / "intrinsic_color.txt", K4)
    return colors


def write_room_scene(folder: Path, room) -> Path:
    """A `engine.train.rooms.RoomData` (e.g. `box_room()`) written in the ScanNet layout with its
    exact depth as 16-bit millimetres: what `python -m engine synth` writes, minus the ground truth."""
    for name in ("color", "depth", "pose", "intrinsic"):
        (folder / name).mkdir(parents=True, exist_ok=True)
    for i, (image, depth, pose) in enumerate(zip(room.images, room.depths, room.poses)):
        cv2.imwrite(str(folder / "color" / f"{i}.jpg"), image[..., ::-1])
        cv2.imwrite(str(folder / "depth" / f"{i}.png"), np.round(depth * 1000).astype(np.uint16))
        np.savetxt(folder / "pose" / f"{i}.txt", pose)
    K4 = np.eye(4)
    K4[:3, :3] = room.K[0]
    np.savetxt(folder / "intrinsic" / "intrinsic_color.txt", K4)
    return folder


def write_video(path: Path, frames_rgb: Sequence[np.ndarray], fps: float) -> Path:
    """MPEG-4 (mp4v) video of RGB frames, all of one size."""
    height, width = frames_rgb[0].shape[:2]
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    assert writer.isOpened(), "OpenCV cannot write mp4v video here"
    for rgb in frames_rgb:
        writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def rotation_about(axis: Sequence[float], degrees: float) -> np.ndarray:
    """(3, 3) rotation by `degrees` about `axis` (Rodrigues)."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    x = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(degrees)
    return np.eye(3) + np.sin(a) * x + (1 - np.cos(a)) * x @ x


def perturbed_poses(truth: list[np.ndarray], rng: np.random.Generator, max_shift: float = 0.03) -> list[np.ndarray]:
    """Each pose turned 0.5-2 deg about a random axis (in the camera frame) and moved up to `max_shift`
    metres per axis: tracker poses slightly off against the photos, for pose check and refinement tests."""
    out = []
    for pose in truth:
        p = pose.copy()
        p[:3, :3] = pose[:3, :3] @ rotation_about(rng.standard_normal(3), rng.uniform(0.5, 2.0))
        p[:3, 3] += rng.uniform(-max_shift, max_shift, 3)
        out.append(p)
    return out


def room_line_segments(vertical: bool = True) -> list[tuple[np.ndarray, np.ndarray]]:
    """3D segments of a 6 x 5 x 2.6 m room (x 0..6, y 0..5, z up): door frames and corners (vertical,
    unless `vertical` is False) and wall seams (horizontal)."""
    segments = []
    if vertical:
        for x in np.linspace(0.5, 5.5, 9):
            segments += [(np.array([x, 0.0, 0.0]), np.array([x, 0.0, 2.1])),
                         (np.array([x, 5.0, 0.0]), np.array([x, 5.0, 2.1]))]
        for y in np.linspace(0.5, 4.5, 7):
            segments += [(np.array([0.0, y, 0.0]), np.array([0.0, y, 2.1])),
                         (np.array([6.0, y, 0.0]), np.array([6.0, y, 2.1]))]
    for z in (0.0, 1.0, 2.6):
        segments += [(np.array([0.0, 0.0, z]), np.array([6.0, 0.0, z])), (np.array([0.0, 5.0, z]), np.array([6.0, 5.0, z])),
                     (np.array([0.0, 0.0, z]), np.array([0.0, 5.0, z])), (np.array([6.0, 0.0, z]), np.array([6.0, 5.0, z]))]
    return segments


def draw_room_lines(folder: Path, poses: Sequence[np.ndarray], K: np.ndarray, size: tuple[int, int],
                    vertical: bool = True) -> list:
    """A grey photo per camera (folder/NNN.png) with `room_line_segments` drawn in white where they lie
    in front of it; returns the engine Frames (path, size, K, pose)."""
    from engine.capture.model import Frame

    frames = []
    for index, pose in enumerate(poses):
        image = np.full((size[1], size[0], 3), 90, np.uint8)
        for a, b in room_line_segments(vertical):
            # Cut the segment to the part in front of the camera, then draw its projection.
            depth_a, depth_b = (np.linalg.inv(pose) @ np.r_[a, 1.0])[2], (np.linalg.inv(pose) @ np.r_[b, 1.0])[2]
            if max(depth_a, depth_b) < 0.2:
                continue
            if min(depth_a, depth_b) < 0.2:
                cut = a + (0.2 - depth_a) / (depth_b - depth_a) * (b - a)
                a, b = (cut, b) if depth_a < 0.2 else (a, cut)
            u, v, _ = project_points(np.stack([a, b]), K, pose)
            ends = np.clip(np.column_stack([u, v]), -5000, 5000).round().astype(int)
            cv2.line(image, tuple(map(int, ends[0])), tuple(map(int, ends[1])), (235, 235, 235), 3, cv2.LINE_AA)
        path = folder / f"{index:03d}.png"
        cv2.imwrite(str(path), image)
        frames.append(Frame(path, size[0], size[1], np.asarray(K, np.float64).copy(), np.asarray(pose, np.float64)))
    return frames
