"""Bundle adjustment that keeps the given trajectory's gauge: camera positions held (or tied to priors).

Why our own: given poses (tracker, ARKit, SLAM, RGB-D rig) carry the capture's scale in their camera
centres. COLMAP's adjuster frees every camera and fixes the gauge with two of them, so a weakly
linked stretch of the trajectory can come back rescaled (the SUN3D study room's first stretch by
13-19 %, docs/experiments.md), and pycolmap 4.2.1 can hold a pose only whole. Here the camera centres
are constants (first pass) or parameters tied to the given centres by a Gaussian prior (second
pass), so no stretch can change scale. With positions held, the unknowns are small per camera
(a rotation, plus one focal scale per group of cameras sharing intrinsics), the points are eliminated
by the Schur complement and the reduced camera system is dense and small, so an adjustment of a
hundred photos and tens of thousands of observations takes seconds in numpy (COLMAP's rounds over
the same took minutes on two cores).

Model, per observation o of point p in camera c (OpenCV axes, pixels of the photos matched):
    y = R_c (X_p - C_c),   u = s_g fx_c y_x / y_z + cx_c,   v = s_g fy_c y_y / y_z + cy_c
with the rotation updated on the left (R <- exp([w]x) R), s_g the focal scale of camera c's
intrinsics group (1 = as given) and a Cauchy loss on the pixel residual's length (IRLS weights)
against the remaining wrong matches. Levenberg-Marquardt with Marquardt's diagonal damping.

Public API:
- `Tracks`: observations (camera, point, uv) and the points' starting positions;
- `AdjustOptions`, `adjust(K, groups, cam_from_world, tracks, options) -> Adjusted`;
- `reprojection_errors(K, focal_scale, groups, cam_from_world, points, tracks) -> (O,) px`;
- `cam_from_world_of(c2w)`, `cam_to_world_of(cam_from_world)`: the engine's (4, 4) camera-to-world
  poses to COLMAP's (3, 4) world-to-camera ones, which the adjustment and the worker speak, and back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

from ..capture.geometry import camera_to_world_from_world_to_camera


@dataclass
class Tracks:
    camera: np.ndarray  # (O,) int64 camera index of each observation
    point: np.ndarray  # (O,) int64 point index of each observation
    uv: np.ndarray  # (O, 2) float64 observed pixel position
    points: np.ndarray  # (P,) -> (P, 3) float64 starting world positions (triangulated with the given poses)

    def __post_init__(self) -> None:
        self.camera = np.asarray(self.camera, dtype=np.int64)
        self.point = np.asarray(self.point, dtype=np.int64)
        self.uv = np.asarray(self.uv, dtype=np.float64).reshape(-1, 2)
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        if not (len(self.camera) == len(self.point) == len(self.uv)):
            raise ValueError("Tracks: camera, point and uv must have one entry per observation")


@dataclass
class AdjustOptions:
    # None: camera centres held at the given ones; else the prior's standard deviation (world units,
    # per axis) that ties each centre to its given position, weighed like one pixel of reprojection:
    # one for every camera, or (C,) one per camera (a tiny one holds that camera's centre).
    position_sigma: Optional[Union[float, np.ndarray]] = None
    # Each rotation is tied to its given one by a Gaussian prior of this many degrees, weighed like one
    # pixel of reprojection: far weaker than the photos wherever they constrain a rotation, it pins the
    # directions they leave free (with centres held along a straight stretch, turning every camera
    # about that line moves no centre: on the SUN3D room such a roll of 6-13 deg cost nothing).
    rotation_sigma_deg: Union[float, np.ndarray] = 2.0  # or (C,) one per camera
    refine_focal: bool = False  # one focal scale per intrinsics group (a tracker's K can be a little off)
    loss_scale_px: float = 1.0  # Cauchy loss scale: residuals beyond this weigh less and less
    outlier_px: float = 4.0  # after a first solve, observations farther than this are dropped, then solved again
    max_iterations: int = 25  # Levenberg-Marquardt iterations per solve
    tolerance: float = 1e-6  # stop when the cost falls by less than this fraction


@dataclass
class Adjusted:
    cam_from_world: np.ndarray  # (C, 3, 4) adjusted world-to-camera poses
    focal_scale: np.ndarray  # (G,) focal scale per intrinsics group (1 = as given)
    points: np.ndarray  # (P, 3) adjusted points
    inlier: np.ndarray  # (O,) bool: observations kept (within outlier_px at the end)
    error_given_px: float  # mean reprojection error of the inliers with the given cameras (points fitted to them)
    error_adjusted_px: float  # ... with the adjusted cameras
    iterations: int  # Levenberg-Marquardt iterations in all
    constrained_points: np.ndarray  # (P,) bool: points that kept two or more inlier observations


def rodrigues(w: np.ndarray) -> np.ndarray:
    """(N, 3) axis-angle -> (N, 3, 3) rotation matrices (`log_rotations` is its inverse)."""
    w = np.asarray(w, dtype=np.float64).reshape(-1, 3)
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    cross = _skew(w / np.where(small, 1.0, theta)[:, None])
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    rotation = np.eye(3)[None] + s * cross + (1.0 - c) * (cross @ cross)
    rotation[small] = np.eye(3)
    return rotation


def log_rotations(rotation: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices -> (N, 3) axis-angle (angles below 180 deg). The angle from atan2
    of the skew part and the trace: arccos of the trace alone loses precision near 0."""
    rotation = np.asarray(rotation, dtype=np.float64).reshape(-1, 3, 3)
    skew = np.stack([rotation[:, 2, 1] - rotation[:, 1, 2], rotation[:, 0, 2] - rotation[:, 2, 0],
                     rotation[:, 1, 0] - rotation[:, 0, 1]], axis=1)
    sin = 0.5 * np.linalg.norm(skew, axis=1)
    angle = np.arctan2(sin, 0.5 * (np.trace(rotation, axis1=1, axis2=2) - 1.0))
    factor = np.where(sin > 1e-12, angle / (2.0 * np.where(sin > 1e-12, sin, 1.0)), 0.5)
    return skew * factor[:, None]


def _skew(v: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) cross-product matrices [v]x."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -v[:, 2], v[:, 1]
    out[:, 1, 0], out[:, 1, 2] = v[:, 2], -v[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -v[:, 1], v[:, 0]
    return out


class _Problem:
    """The state of one adjustment: rotations, centres, focal scales and points."""

    def __init__(self, K: np.ndarray, groups: np.ndarray, cam_from_world: np.ndarray, tracks: Tracks,
                 options: AdjustOptions) -> None:
        self.K = np.asarray(K, dtype=np.float64).reshape(-1, 3, 3)
        self.groups = np.asarray(groups, dtype=np.int64)
        self.num_groups = int(self.groups.max()) + 1 if len(self.groups) else 0
        pose = np.asarray(cam_from_world, dtype=np.float64).reshape(-1, 3, 4)
        self.rotation = pose[:, :, :3].copy()
        self.centre = -np.einsum("cji,cj->ci", self.rotation, pose[:, :, 3])  # C = -R^T t
        self.given_centre = self.centre.copy()
        self.given_rotation = self.rotation.copy()
        self.focal_scale = np.ones(self.num_groups)
        self.points = tracks.points.copy()
        self.tracks = tracks
        self.options = options
        self.free_positions = options.position_sigma is not None
        rotation_sigma = np.broadcast_to(np.radians(np.asarray(options.rotation_sigma_deg, dtype=np.float64)), (len(pose),))
        self.rotation_prior = 1.0 / rotation_sigma ** 2  # (C,) per radian^2
        if self.free_positions:  # (C,) 1 / sigma^2 of each camera's centre prior
            sigma = np.broadcast_to(np.asarray(options.position_sigma, dtype=np.float64), (len(pose),))
            self.position_prior = 1.0 / sigma ** 2
        self.per_camera = 6 if self.free_positions else 3
        self.focal_params = self.num_groups if options.refine_focal else 0

    # --- residuals and Jacobians -----------------------------------------------------------------
    def project(self, use: np.ndarray, rotation=None, centre=None, focal_scale=None, points=None):
        """Residuals (O', 2) and camera-space points (O', 3) of the observations `use` (indices)."""
        rotation = self.rotation if rotation is None else rotation
        centre = self.centre if centre is None else centre
        focal_scale = self.focal_scale if focal_scale is None else focal_scale
        points = self.points if points is None else points
        cam, pt = self.tracks.camera[use], self.tracks.point[use]
        y = np.einsum("oij,oj->oi", rotation[cam], points[pt] - centre[cam])
        K = self.K[cam]
        scale = focal_scale[self.groups[cam]]
        z = np.where(np.abs(y[:, 2]) < 1e-9, 1e-9, y[:, 2])
        u = scale * K[:, 0, 0] * y[:, 0] / z + K[:, 0, 2]
        v = scale * K[:, 1, 1] * y[:, 1] / z + K[:, 1, 2]
        return np.stack([u, v], axis=1) - self.tracks.uv[use], y

    def rotation_offsets(self, rotation=None) -> np.ndarray:
        """(C, 3) axis-angle w with R = exp([w]x) R_given, the rotations' distance from the given ones."""
        rotation = self.rotation if rotation is None else rotation
        return log_rotations(np.einsum("cij,ckj->cik", rotation, self.given_rotation))

    def cost(self, residual: np.ndarray, y: np.ndarray, centre=None, rotation=None) -> float:
        c2 = self.options.loss_scale_px ** 2
        squared = np.sum(residual ** 2, axis=1)
        behind = y[:, 2] <= 1e-6
        total = float(np.sum(c2 * np.log1p(np.where(behind, 0.0, squared) / c2))) + float(behind.sum()) * 1e6
        total += float(np.sum(np.sum(self.rotation_offsets(rotation) ** 2, axis=1) * self.rotation_prior))
        if self.free_positions:
            centre = self.centre if centre is None else centre
            total += float(np.sum(np.sum((centre - self.given_centre) ** 2, axis=1) * self.position_prior))
        return total

    def step(self, use: np.ndarray, damping: float, move_cameras: bool = True):
        """One Gauss-Newton step (damped) for observations `use`: (camera update (C, k), focal update (G,),
        point update (P, 3)); cameras untouched when `move_cameras` is False (points fitted to them)."""
        residual, y = self.project(use)
        cam, pt = self.tracks.camera[use], self.tracks.point[use]
        K = self.K[cam]
        scale = self.focal_scale[self.groups[cam]]
        count = len(use)
        c2 = self.options.loss_scale_px ** 2
        weight = 1.0 / (1.0 + np.sum(residual ** 2, axis=1) / c2)
        weight[y[:, 2] <= 1e-6] = 0.0
        root = np.sqrt(weight)[:, None, None]
        z = np.where(np.abs(y[:, 2]) < 1e-9, 1e-9, y[:, 2])
        fx, fy = scale * K[:, 0, 0], scale * K[:, 1, 1]
        A = np.zeros((count, 2, 3))  # d(u, v) / dy
        A[:, 0, 0], A[:, 0, 2] = fx / z, -fx * y[:, 0] / z ** 2
        A[:, 1, 1], A[:, 1, 2] = fy / z, -fy * y[:, 1] / z ** 2
        R = self.rotation[cam]
        J_point = root * (A @ R)  # (O, 2, 3)
        r = np.sqrt(weight)[:, None] * residual  # (O, 2) weighted residuals
        num_points = len(self.points)

        # Points' 3x3 blocks and gradient.
        blocks = np.einsum("oki,okj->oij", J_point, J_point).reshape(count, 9)
        V = np.stack([np.bincount(pt, blocks[:, k], minlength=num_points) for k in range(9)], axis=1).reshape(-1, 3, 3)
        g_point_o = np.einsum("oki,ok->oi", J_point, r)
        g_point = np.stack([np.bincount(pt, g_point_o[:, k], minlength=num_points) for k in range(3)], axis=1)
        V = V + damping * np.einsum("pii->pi", V)[:, :, None] * np.eye(3) + 1e-9 * np.eye(3)
        observed = np.bincount(pt, minlength=num_points) > 0
        V[~observed] = np.eye(3)
        V_inv = _inverse_3x3(V)
        if not move_cameras:
            point_step = -np.einsum("pij,pj->pi", V_inv, g_point)
            return np.zeros((len(self.rotation), self.per_camera)), np.zeros(self.num_groups), point_step

        # Camera-side Jacobian: rotation (3) [+ centre (3)] per camera, then focal scales.
        blocks_cam = [root * (A @ -_skew(y))]
        if self.free_positions:
            blocks_cam.append(root * (A @ -R))
        J_cam = np.concatenate(blocks_cam, axis=2)  # (O, 2, k)
        k = self.per_camera
        num_cams = len(self.rotation)
        n_cam = num_cams * k + self.focal_params
        rows = np.arange(2 * count).reshape(count, 2)
        cols = cam[:, None] * k + np.arange(k)[None]
        data, row_index, col_index = [J_cam.reshape(count, 2 * k)], [np.repeat(rows, k, axis=1)], [np.tile(cols, (1, 2))]
        if self.focal_params:
            J_focal = root[:, :, 0] * np.stack([K[:, 0, 0] * y[:, 0] / z, K[:, 1, 1] * y[:, 1] / z], axis=1)
            data.append(J_focal)
            row_index.append(rows)
            col_index.append(np.repeat((num_cams * k + self.groups[cam])[:, None], 2, axis=1))
        import scipy.sparse as sparse  # defers scipy: not loaded when Blender registers the extension

        Jc = sparse.csr_matrix((np.concatenate([d.ravel() for d in data]),
                                (np.concatenate([i.ravel() for i in row_index]),
                                 np.concatenate([j.ravel() for j in col_index]))), shape=(2 * count, n_cam))
        Jp = sparse.csr_matrix((J_point.reshape(-1),
                                (np.repeat(np.arange(2 * count), 3), (pt[:, None] * 3 + np.arange(3)[None]).repeat(2, axis=0).ravel())),
                               shape=(2 * count, 3 * num_points))
        r_flat = r.reshape(-1)
        U = (Jc.T @ Jc).toarray()
        g_cam = Jc.T @ r_flat
        W = (Jc.T @ Jp).tocsr()  # (n_cam, 3P)
        rotation_prior = np.repeat(self.rotation_prior, 3)
        index = (np.arange(num_cams)[:, None] * k + np.arange(3)[None]).ravel()
        U[index, index] += rotation_prior
        g_cam[index] += rotation_prior * self.rotation_offsets().ravel()
        if self.free_positions:
            prior = np.repeat(self.position_prior, 3)
            index = (np.arange(num_cams)[:, None] * k + np.arange(3, 6)[None]).ravel()
            U[index, index] += prior
            g_cam[index] += prior * (self.centre - self.given_centre).ravel()
        U[np.diag_indices(n_cam)] *= 1.0 + damping
        U[np.diag_indices(n_cam)] += 1e-9
        WV = W @ _block_diagonal(V_inv)
        S = U - (WV @ W.T).toarray()
        rhs = -g_cam + WV @ g_point.ravel()
        camera_step = np.linalg.solve(S, rhs)
        point_rhs = -g_point.ravel() - W.T @ camera_step
        point_step = np.einsum("pij,pj->pi", V_inv, point_rhs.reshape(-1, 3))
        focal_step = camera_step[num_cams * k:] if self.focal_params else np.zeros(self.num_groups)
        return camera_step[: num_cams * k].reshape(num_cams, k), focal_step, point_step

    def trial(self, camera_step, focal_step, point_step):
        rotation = rodrigues(camera_step[:, :3]) @ self.rotation
        centre = self.centre + camera_step[:, 3:6] if self.free_positions else self.centre
        return rotation, centre, self.focal_scale + focal_step, self.points + point_step

    def solve(self, use: np.ndarray, move_cameras: bool = True) -> int:
        """Levenberg-Marquardt on the observations `use`; returns the iterations taken."""
        damping = 1e-4
        residual, y = self.project(use)
        current = self.cost(residual, y)
        iterations = 0
        for _ in range(self.options.max_iterations):
            iterations += 1
            camera_step, focal_step, point_step = self.step(use, damping, move_cameras)
            rotation, centre, focal_scale, points = self.trial(camera_step, focal_step, point_step)
            residual, y = self.project(use, rotation, centre, focal_scale, points)
            candidate = self.cost(residual, y, centre, rotation)
            if candidate < current:
                self.rotation, self.centre, self.focal_scale, self.points = rotation, centre, focal_scale, points
                converged = (current - candidate) < self.options.tolerance * current
                current = candidate
                damping = max(damping / 3.0, 1e-7)
                if converged:
                    break
            else:
                damping *= 10.0
                if damping > 1e6:
                    break
        return iterations

    def cam_from_world(self) -> np.ndarray:
        t = -np.einsum("cij,cj->ci", self.rotation, self.centre)
        return np.concatenate([self.rotation, t[:, :, None]], axis=2)


def _inverse_3x3(m: np.ndarray) -> np.ndarray:
    """(N, 3, 3) -> (N, 3, 3) inverses by the adjugate: batched LAPACK spends ~100x longer on 3x3s.
    The blocks are damped normal-equation blocks (positive definite), so the determinant is > 0."""
    a, b, c = m[:, 0, 0], m[:, 0, 1], m[:, 0, 2]
    d, e, f = m[:, 1, 0], m[:, 1, 1], m[:, 1, 2]
    g, h, i = m[:, 2, 0], m[:, 2, 1], m[:, 2, 2]
    co = np.stack([e * i - f * h, c * h - b * i, b * f - c * e,
                   f * g - d * i, a * i - c * g, c * d - a * f,
                   d * h - e * g, b * g - a * h, a * e - b * d], axis=1).reshape(-1, 3, 3)
    det = a * co[:, 0, 0] + b * co[:, 1, 0] + c * co[:, 2, 0]
    return co / det[:, None, None]


def _block_diagonal(blocks: np.ndarray) -> "scipy.sparse.csr_matrix":
    """(P, 3, 3) -> sparse (3P, 3P) block-diagonal matrix."""
    import scipy.sparse as sparse  # defers scipy: not loaded when Blender registers the extension

    count = len(blocks)
    base = (np.arange(count) * 3)[:, None, None]
    rows = np.broadcast_to(base + np.arange(3)[None, :, None], (count, 3, 3))
    cols = np.broadcast_to(base + np.arange(3)[None, None, :], (count, 3, 3))
    return sparse.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * count, 3 * count))


def reprojection_errors(K: np.ndarray, focal_scale: np.ndarray, groups: np.ndarray, cam_from_world: np.ndarray,
                        points: np.ndarray, tracks: Tracks) -> np.ndarray:
    """(O,) pixel distance between each observation and its point's projection (inf behind the camera)."""
    problem = _Problem(K, groups, cam_from_world, Tracks(tracks.camera, tracks.point, tracks.uv, points),
                       AdjustOptions(refine_focal=False))
    problem.focal_scale = np.asarray(focal_scale, dtype=np.float64)
    residual, y = problem.project(np.arange(len(tracks.camera)))
    error = np.linalg.norm(residual, axis=1)
    error[y[:, 2] <= 1e-6] = np.inf
    return error


def adjust(K: np.ndarray, groups: np.ndarray, cam_from_world: np.ndarray, tracks: Tracks,
           options: Optional[AdjustOptions] = None) -> Adjusted:
    """Adjust rotations, focal scales and points (and centres within priors, when asked) to the tracks.

    K: (C, 3, 3) intrinsics in the tracks' pixels; groups: (C,) int, cameras sharing one focal scale;
    cam_from_world: (C, 3, 4) given world-to-camera poses; tracks: observations and starting points.
    Solves once, drops observations beyond options.outlier_px, solves again. The given cameras'
    error is measured on the same final observations with the points fitted to the given cameras,
    so the two errors compare like with like.
    """
    options = options or AdjustOptions()
    problem = _Problem(K, groups, cam_from_world, tracks, options)
    use = np.arange(len(tracks.camera))
    iterations = problem.solve(use)
    residual, y = problem.project(use)
    inlier = (np.linalg.norm(residual, axis=1) <= options.outlier_px) & (y[:, 2] > 1e-6)
    # A point needs two views to be constrained.
    inlier &= np.bincount(tracks.point[inlier], minlength=len(tracks.points))[tracks.point] >= 2
    use = np.flatnonzero(inlier)
    iterations += problem.solve(use)
    residual, _ = problem.project(use)
    error_adjusted = float(np.mean(np.linalg.norm(residual, axis=1))) if len(use) else float("nan")

    given = _Problem(K, groups, cam_from_world, Tracks(tracks.camera, tracks.point, tracks.uv, problem.points),
                     options)
    given.solve(use, move_cameras=False)
    residual, _ = given.project(use)
    error_given = float(np.mean(np.linalg.norm(residual, axis=1))) if len(use) else float("nan")
    constrained = np.bincount(tracks.point[inlier], minlength=len(tracks.points)) >= 2
    return Adjusted(problem.cam_from_world(), problem.focal_scale.copy(), problem.points.copy(), inlier,
                    error_given, error_adjusted, iterations, constrained)


def cam_from_world_of(c2w: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world -> COLMAP's (3, 4) world-to-camera [R^T | -R^T t]."""
    rotation = c2w[:3, :3].T
    return np.hstack([rotation, (-rotation @ c2w[:3, 3])[:, None]])


def cam_to_world_of(cam_from_world: np.ndarray) -> np.ndarray:
    """COLMAP's (3, 4) world-to-camera [R | t] -> (4, 4) camera-to-world [R^T | -R^T t]."""
    return camera_to_world_from_world_to_camera(cam_from_world[:, :3], cam_from_world[:, 3])
