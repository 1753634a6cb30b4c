"""A procedurally generated posed capture: cameras on a circle inside a textured box room.

Used by the benchmark and the tests; no Blender needed. Images are ray-cast in numpy against the
room's six walls with a random per-cell colour texture (0.25 m cells), so they are consistent with
the poses, but the numbers this capture gives measure speed, not reconstruction quality.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..capture import Capture, Frame
from ..geometry.cameras import look_along

CELL = 0.25  # texture cell size in metres
PALETTE = 64  # texture repeats every 64 cells


def intrinsics(width: int, height: int, fov_deg: float) -> np.ndarray:
    """K (3, 3) for a horizontal field of view; principal point at the image centre."""
    f = width / 2 / np.tan(np.deg2rad(fov_deg) / 2)
    return np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=np.float64)


def circle_poses(frames: int, centre: np.ndarray, radius: float, pitch_deg: float = -10.0, outward_deg: float = 60.0) -> np.ndarray:
    """(frames, 4, 4) cameras on a horizontal circle, looking `outward_deg` away from the tangent
    (90 = straight out at the walls, -90 = straight in at the centre) and tilted down by -pitch_deg,
    as a person scanning a room walks."""
    poses = []
    for i in range(frames):
        angle = 2 * np.pi * i / frames
        position = centre + radius * np.array([np.cos(angle), np.sin(angle), 0.0])
        heading = angle + np.pi / 2 - np.deg2rad(outward_deg)
        pitch = np.deg2rad(pitch_deg)
        forward = np.array([np.cos(heading) * np.cos(pitch), np.sin(heading) * np.cos(pitch), np.sin(pitch)])
        poses.append(look_along(position, forward))
    return np.stack(poses)


def render_box_room(K: np.ndarray, pose: np.ndarray, size: tuple[int, int], room_size: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast the inside of the box [0, room_size] from a camera inside it.

    Returns the image (h, w, 3) uint8 RGB and planar depth (h, w) float32 in metres.
    """
    w, h = size
    palette = np.random.default_rng(seed).integers(30, 226, size=(6, PALETTE, PALETTE, 3), dtype=np.uint8)
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays_cam = np.stack([cols, rows, np.ones_like(cols)], -1) @ np.linalg.inv(K).T  # z = 1: planar depth
    rays = rays_cam @ pose[:3, :3].T  # (h, w, 3) world directions
    c = pose[:3, 3]
    safe = np.where(np.abs(rays) > 1e-12, rays, 1e-12)
    t_axis = np.where(rays > 0, (np.asarray(room_size) - c) / safe, (0.0 - c) / safe)  # (h, w, 3)
    axis = np.argmin(t_axis, axis=-1)
    t = np.take_along_axis(t_axis, axis[..., None], -1)[..., 0]
    hit = c + t[..., None] * rays
    face = axis * 2 + (np.take_along_axis(rays, axis[..., None], -1)[..., 0] > 0)
    # Texture coordinates: the two world axes lying in the hit wall.
    other = np.stack([(axis + 1) % 3, (axis + 2) % 3], -1)
    uv = np.take_along_axis(hit, other, -1)
    cell = np.floor(uv / CELL).astype(np.int64) % PALETTE
    image = palette[face, cell[..., 0], cell[..., 1]]
    return image, t.astype(np.float32)


def make_synthetic_capture(
    directory: Path,
    room_size: tuple[float, float, float] = (4.0, 4.0, 2.5),
    frames: int = 40,
    image_size: tuple[int, int] = (320, 240),
    fov_deg: float = 60.0,
    radius: float = 0.8,
    height: float = 1.5,
    seed: int = 0,
    outward_deg: float = 60.0,
) -> Capture:
    """Render `frames` views into `directory` in the ScanNet layout that `load_capture` reads
    (color/<i>.png, pose/<i>.txt camera-to-world, intrinsic/intrinsic_color.txt) and return the
    posed, metric Capture. outward_deg: see `circle_poses` (negative looks inward, across the room)."""
    directory = Path(directory)
    for sub in ("color", "pose", "intrinsic"):
        (directory / sub).mkdir(parents=True, exist_ok=True)
    room = np.asarray(room_size, dtype=np.float64)
    K = intrinsics(*image_size, fov_deg)
    K4 = np.eye(4)
    K4[:3, :3] = K
    np.savetxt(directory / "intrinsic" / "intrinsic_color.txt", K4)
    poses = circle_poses(frames, np.array([room[0] / 2, room[1] / 2, height]), radius, outward_deg=outward_deg)
    out = []
    for i, pose in enumerate(poses):
        image, _ = render_box_room(K, pose, image_size, room, seed)
        path = directory / "color" / f"{i}.png"
        cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        np.savetxt(directory / "pose" / f"{i}.txt", pose)
        out.append(Frame(image_path=path, width=image_size[0], height=image_size[1], K=K.copy(), pose=pose))
    return Capture(root=directory, format="scannet", frames=out, metric=True)
