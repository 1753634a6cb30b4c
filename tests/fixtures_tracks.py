"""Synthetic rooms with known cameras and feature tracks, for the pose refinement's bundle adjustment
tests: the truth is known exactly, no photos or COLMAP needed."""

from __future__ import annotations

import numpy as np

from engine.poses.adjust import Tracks

F, W, H = 500.0, 640, 480
K = np.array([[F, 0.0, W / 2], [0.0, F, H / 2], [0.0, 0.0, 1.0]])


def look(centre: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World-to-camera rotation (3, 3) of a level camera at `centre` looking at `target` (OpenCV axes)."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def wall_points(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count, 3) points on the four walls of a 6 x 5 x 3 m room centred on the origin."""
    per = count // 4
    u, h = rng.uniform(-1, 1, (4, per)), rng.uniform(0.0, 3.0, (4, per))
    return np.concatenate([np.stack([3 * u[0], np.full(per, 2.5), h[0]], 1),
                           np.stack([3 * u[1], np.full(per, -2.5), h[1]], 1),
                           np.stack([np.full(per, 3.0), 2.5 * u[2], h[2]], 1),
                           np.stack([np.full(per, -3.0), 2.5 * u[3], h[3]], 1)])


def observe(rotations: np.ndarray, centres: np.ndarray, points: np.ndarray, rng: np.random.Generator,
            noise_px: float = 0.3, outliers: float = 0.0) -> tuple[Tracks, np.ndarray]:
    """Tracks of every point each true camera sees (2+ views), pixel noise, a share of wrong matches.
    Returns (tracks with the true points, (O,) bool: the observation is a wrong match)."""
    cams, pts, uvs = [], [], []
    for c, (R, C) in enumerate(zip(rotations, centres)):
        y = (points - C) @ R.T
        uv = F * y[:, :2] / np.maximum(y[:, 2:3], 1e-9) + [W / 2, H / 2]
        seen = np.flatnonzero((y[:, 2] > 0.3) & (uv[:, 0] > 0) & (uv[:, 0] < W) & (uv[:, 1] > 0) & (uv[:, 1] < H))
        cams.append(np.full(len(seen), c))
        pts.append(seen)
        uvs.append(uv[seen] + rng.normal(0.0, noise_px, (len(seen), 2)))
    camera, point, uv = np.concatenate(cams), np.concatenate(pts), np.concatenate(uvs)
    keep = np.bincount(point, minlength=len(points))[point] >= 2
    camera, point, uv = camera[keep], point[keep], uv[keep]
    wrong = rng.random(len(uv)) < outliers
    uv[wrong] += rng.choice([-1, 1], (wrong.sum(), 2)) * rng.uniform(15, 40, (wrong.sum(), 2))
    return Tracks(camera, point, uv, points), wrong


def ring_room(rng: np.random.Generator, cameras: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rotations (C, 3, 3), centres (C, 3), points (P, 3)): a walk around a room looking at its walls."""
    angle = np.linspace(0, 2 * np.pi, cameras, endpoint=False)
    centres = np.stack([np.cos(angle), 0.8 * np.sin(angle), 1.4 + 0.05 * np.sin(3 * angle)], 1)
    rotations = np.stack([look(c, c + [np.cos(a + 0.3), np.sin(a + 0.3), -0.1]) for c, a in zip(centres, angle)])
    return rotations, centres, wall_points(rng, 3000)


def cam_from_world(rotations: np.ndarray, centres: np.ndarray) -> np.ndarray:
    return np.concatenate([rotations, -np.einsum("cij,cj->ci", rotations, centres)[:, :, None]], axis=2)


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(C,) angle between rotation stacks a and b (C, 3, 3)."""
    cos = 0.5 * (np.einsum("cij,cij->c", a, b) - 1.0)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def centres_of(pose: np.ndarray) -> np.ndarray:
    return -np.einsum("cji,cj->ci", pose[:, :, :3], pose[:, :, 3])
