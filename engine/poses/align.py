"""Similarity transforms between camera trajectories: Umeyama fit, applying a Sim(3), pose errors.

SfM recovers poses only up to a similarity (rotation, translation, scale), so every comparison
with ground truth and every change of world frame (gravity, metric scale) goes through here.
Poses are camera-to-world (4, 4) float64 in OpenCV camera axes, as everywhere in the engine.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class Similarity:
    """x_new = scale * rotation @ x + translation."""

    rotation: np.ndarray  # (3, 3) float64, det +1
    translation: np.ndarray  # (3,) float64
    scale: float = 1.0

    @staticmethod
    def identity() -> "Similarity":
        return Similarity(np.eye(3), np.zeros(3), 1.0)

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix of the similarity."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = self.translation
        return m

    def apply_points(self, points: np.ndarray) -> np.ndarray:
        """points (N, 3) -> (N, 3)."""
        return self.scale * np.asarray(points, dtype=np.float64) @ self.rotation.T + self.translation

    def apply_pose(self, cam_to_world: np.ndarray) -> np.ndarray:
        """Move a camera (4, 4) camera-to-world into the new world: [R_w R_c | s R_w t_c + t_w].

        The camera's own axes only rotate; the scale acts on positions, never on the rotation
        block, so the result stays a rigid camera-to-world matrix.
        """
        out = np.eye(4)
        out[:3, :3] = self.rotation @ cam_to_world[:3, :3]
        out[:3, 3] = self.scale * self.rotation @ cam_to_world[:3, 3] + self.translation
        return out

    def then(self, other: "Similarity") -> "Similarity":
        """The similarity that applies `self` first and `other` second."""
        return Similarity(
            other.rotation @ self.rotation,
            other.scale * other.rotation @ self.translation + other.translation,
            other.scale * self.scale,
        )

    def inverse(self) -> "Similarity":
        """The similarity that undoes this one: x = (1/s) R^T x_new - (1/s) R^T t."""
        rotation = self.rotation.T
        return Similarity(rotation, -(rotation @ self.translation) / self.scale, 1.0 / self.scale)

    def apply_directions(self, directions: np.ndarray) -> np.ndarray:
        """Directions (N, 3) (normals, view rays) -> (N, 3): only rotated; scale and translation move points."""
        return np.asarray(directions, dtype=np.float64) @ self.rotation.T

    def to_dict(self) -> dict:
        """JSON-ready: rotation (3 x 3 rows), translation (3), scale, and the 4 x 4 matrix, x_new = s R x + t."""
        return {"rotation": self.rotation.tolist(), "translation": self.translation.tolist(), "scale": float(self.scale),
                "matrix": self.matrix().tolist()}


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool = True) -> Similarity:
    """Least-squares similarity with target ~ s R source + t (Umeyama 1991).

    source, target: (N, 3) corresponding points, N >= 3 and not all collinear for a unique R.
    """
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"umeyama needs two (N, 3) arrays with N >= 3, got {src.shape} and {dst.shape}")
    mu_src, mu_dst = src.mean(0), dst.mean(0)
    src_c, dst_c = src - mu_src, dst - mu_dst
    covariance = dst_c.T @ src_c / len(src)
    u, d, vt = np.linalg.svd(covariance)
    # Reflection guard: force det(R) = +1 by flipping the weakest singular direction.
    sign = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2] = -1.0
    rotation = u @ np.diag(sign) @ vt
    variance = (src_c**2).sum() / len(src)
    scale = float((d * sign).sum() / variance) if with_scale and variance > 0 else 1.0
    translation = mu_dst - scale * rotation @ mu_src
    return Similarity(rotation, translation, scale)


def fit_pose_similarity(source_c2w: np.ndarray, target_c2w: np.ndarray) -> Similarity:
    """Similarity taking camera trajectory `source_c2w` (N, 4, 4) onto `target_c2w` (N, 4, 4), N >= 1.

    Unlike `umeyama` on the camera centres alone, the rotation comes from the cameras'
    orientations (the chordal mean of R_target R_source^T), so it is well defined for a straight
    or short trajectory, where centres leave the roll about the line free. Scale and translation
    then follow by least squares on the centres (scale 1 for a single camera).
    """
    src = np.asarray(source_c2w, dtype=np.float64)
    dst = np.asarray(target_c2w, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 3 or src.shape[1:] != (4, 4) or len(src) == 0:
        raise ValueError(f"fit_pose_similarity needs two (N, 4, 4) arrays, got {src.shape} and {dst.shape}")
    u, _, vt = np.linalg.svd(np.einsum("nij,nkj->ik", dst[:, :3, :3], src[:, :3, :3]))
    rotation = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    c_src, c_dst = src[:, :3, 3], dst[:, :3, 3]
    mu_src, mu_dst = c_src.mean(0), c_dst.mean(0)
    rotated = (c_src - mu_src) @ rotation.T
    variance = float((rotated**2).sum())
    scale = float((rotated * (c_dst - mu_dst)).sum() / variance) if variance > 1e-18 else 1.0
    return Similarity(rotation, mu_dst - scale * rotation @ mu_src, scale)


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle of a (3, 3) rotation matrix in degrees.

    atan2 of sine (from the skew part) and cosine (from the trace): arccos of the trace alone
    loses precision near 0, exactly where pose errors live.
    """
    skew = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0], rotation[1, 0] - rotation[0, 1]])
    sin = 0.5 * np.linalg.norm(skew)
    cos = 0.5 * (np.trace(rotation) - 1.0)
    return float(np.degrees(np.arctan2(sin, cos)))


def pose_errors(estimated_c2w: Sequence[np.ndarray], true_c2w: Sequence[np.ndarray]) -> dict[str, float]:
    """Compare two trajectories of the same cameras after a Sim(3) fit of the camera centres.

    estimated_c2w, true_c2w: equally long sequences of (4, 4) camera-to-world, OpenCV axes, same order.
    Returns rotation_deg_mean / _max / _median (angle of R_true^T R_aligned per camera),
    position_mean / _max / _median (centre distance in the units of the truth), the fitted `scale`
    (truth units per estimated unit), `up_deg` (median over the cameras of the angle between "up" as
    each camera sees it in the estimated world and in the true one, +Z of both: how far the estimated
    gravity is off, whatever the fit) and `count`.
    """
    if len(estimated_c2w) != len(true_c2w):
        raise ValueError(f"{len(estimated_c2w)} estimated poses but {len(true_c2w)} true poses")
    est = np.asarray(estimated_c2w, dtype=np.float64)
    gt = np.asarray(true_c2w, dtype=np.float64)
    sim = umeyama(est[:, :3, 3], gt[:, :3, 3])
    aligned = np.stack([sim.apply_pose(p) for p in est])
    rot_err = np.array([rotation_angle_deg(g[:3, :3].T @ a[:3, :3]) for g, a in zip(gt, aligned)])
    pos_err = np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1)
    return {
        "rotation_deg_mean": float(rot_err.mean()),
        "rotation_deg_max": float(rot_err.max()),
        "rotation_deg_median": float(np.median(rot_err)),
        "position_mean": float(pos_err.mean()),
        "position_median": float(np.median(pos_err)),
        "position_max": float(pos_err.max()),
        "scale": sim.scale,
        "up_deg": float(np.median(np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", est[:, 2, :3], gt[:, 2, :3]), -1.0, 1.0))))),
        "count": float(len(est)),
    }
