"""An ARKitScenes raw video folder written with plain numpy / OpenCV, as ARKitScenes stores an iPad held
upright: photos in the sensor's landscape orientation (the world's up pointing to the photo's left),
each line of lowres_wide.traj the world-to-camera transform as axis-angle and translation."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from engine.geometry.cameras import look_along, project_points

W, H = 64, 48  # stored (landscape) photo size
K = np.array([[50.0, 0.0, 33.0], [0.0, 50.0, 22.0], [0.0, 0.0, 1.0]])
POINT = np.array([0.3, 2.0, 1.2])  # a world point (Z up, metres) every camera sees


def held_upright_on_its_side(eye, yaw_deg: float) -> np.ndarray:
    """Camera-to-world of an iPad held upright: its landscape sensor's image x points down the world
    (x = the level camera's y), image y to the left of the view (-x of the level camera)."""
    level = look_along(eye, (np.sin(np.radians(yaw_deg)), np.cos(np.radians(yaw_deg)), -0.1))
    pose = level.copy()
    pose[:3, 0], pose[:3, 1] = level[:3, 1], -level[:3, 0]
    return pose


def write_arkitscenes(folder: Path, poses: list[np.ndarray], times: list[float], traj_times=None,
                      depth: bool = True) -> Path:
    """`<folder>/123_frames/` with a photo per pose: grey, a white 3 x 3 marker where POINT projects;
    depth maps in millimetres holding the POINT's depth everywhere."""
    frames = folder / "123_frames"
    for name in ("lowres_wide", "lowres_wide_intrinsics", "lowres_depth"):
        (frames / name).mkdir(parents=True)
    lines = []
    for pose, time, traj_time in zip(poses, times, traj_times or times):
        u, v, z = (float(a[0]) for a in project_points(POINT[None], K, pose))
        photo = np.full((H, W, 3), 60, np.uint8)
        photo[int(v) - 1:int(v) + 2, int(u) - 1:int(u) + 2] = 255
        photo[:, :4, 2] = 200  # the stored photo's left edge: red in the loaded one's top rows
        cv2.imwrite(str(frames / "lowres_wide" / f"123_{time:.3f}.png"), photo)
        (frames / "lowres_wide_intrinsics" / f"123_{time:.3f}.pincam").write_text(
            f"{W} {H} {K[0, 0]} {K[1, 1]} {K[0, 2]} {K[1, 2]}\n")
        if depth:
            cv2.imwrite(str(frames / "lowres_depth" / f"123_{time:.3f}.png"), np.full((H, W), round(1000 * z), np.uint16))
        world_to_camera = np.linalg.inv(pose)
        axis_angle = cv2.Rodrigues(world_to_camera[:3, :3])[0].ravel()
        lines.append(" ".join(f"{x:.9f}" for x in [traj_time, *axis_angle, *world_to_camera[:3, 3]]))
    (frames / "lowres_wide.traj").write_text("\n".join(lines) + "\n")
    return folder


def capture_poses() -> list[np.ndarray]:
    return [held_upright_on_its_side((0.1 * i, 0.0, 1.4), yaw) for i, yaw in enumerate((-8.0, 0.0, 6.0, 12.0))]
