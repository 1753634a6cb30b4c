"""A 3D Scanner App "All Data" export written with plain numpy / OpenCV / json, for tests of the
loader and of Blender's Import Capture."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np

from fixtures_capture import textured_image, write_image

W, H = 64, 48  # photos
DW, DH = 16, 12  # depth maps: the same aspect ratio, as the app writes them (256 x 192 for 1920 x 1440)
K = np.array([[52.0, 0.0, 31.0], [0.0, 52.0, 24.5], [0.0, 0.0, 1.0]])


def arkit_transform(yaw_deg: float, position: tuple[float, float, float]) -> np.ndarray:
    """An ARKit camera-to-world transform: the phone held upright (camera y = world up), turned by
    `yaw_deg` about ARKit's vertical y axis, at `position` (ARKit world, y up, metres)."""
    a = np.radians(yaw_deg)
    transform = np.eye(4)
    transform[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    transform[:3, 3] = position
    return transform


def project_arkit(transform: np.ndarray, point_arkit: np.ndarray) -> tuple[float, float]:
    """Pixel of an ARKit world point, by ARKit's own convention: camera x right, y up, z backward, so a
    point in front has z < 0 and image rows grow downwards (against camera y)."""
    x, y, z = (np.linalg.inv(transform) @ np.append(point_arkit, 1.0))[:3]
    assert z < 0, "the test point must be in front of the camera"
    return K[0, 0] * x / -z + K[0, 2], K[1, 1] * -y / -z + K[1, 2]


def write_export(folder: Path, transforms: list[np.ndarray], every_photo: int = 1, depth: bool = True) -> Path:
    """An "All Data" export: a frame JSON per tracked frame, a photo for every `every_photo`-th, LiDAR
    depth (frame i: a plane at 1 + 0.1 i m, confidence high on the left half, low on the right)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "info.json").write_text(json.dumps({"appVersionString": "1.9.7", "numImages": len(transforms),
                                                  "title": "test room"}))
    for i, transform in enumerate(transforms):
        record = {"cameraPoseARFrame": transform.reshape(-1).tolist(), "intrinsics": K.reshape(-1).tolist(),
                  "frame_index": i, "latitude": 37.54471932286522, "longitude": 126.96394754669224,
                  "altitude": 54.8, "hasGPS": True, "time": 100.0 + i}
        (folder / f"frame_{i:05d}.json").write_text(json.dumps(record))
        if i % every_photo == 0:
            write_image(folder / f"frame_{i:05d}.jpg", textured_image(W, H, seed=i))
        if depth:
            cv2.imwrite(str(folder / f"depth_{i:05d}.png"), np.full((DH, DW), 1000 + 100 * i, np.uint16))
            confidence = np.zeros((DH, DW), np.uint8)
            confidence[:, : DW // 2] = 2
            cv2.imwrite(str(folder / f"conf_{i:05d}.png"), confidence)
    return folder


def walk(count: int) -> list[np.ndarray]:
    return [arkit_transform(10.0 * i, (0.3 * i, 1.4, -0.2 * i)) for i in range(count)]


# The public 3D Scanner App sample (PyojinKim/3dScannerApp_samples, rgbd_dataset_renaissance_03_corridor01/All_Data),
# fetched beside the repository, never committed; VORTX_CORRIDOR points elsewhere.
CORRIDOR = Path(os.environ.get("VORTX_CORRIDOR", Path(__file__).resolve().parents[2] / "data"
                               / "rgbd_dataset_renaissance_03_corridor01" / "All_Data"))
