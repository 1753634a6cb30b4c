"""Camera pose and intrinsics conversions used at the edges, when a file's convention is read.

The engine's convention: pose = camera-to-world (4, 4) float64 with OpenCV camera axes
(x right, y down, z forward); K (3, 3) float64 in pixels, pixel (0, 0) covering [0, 1)^2.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from .images import UnusableImage

# Diagonal that flips the y and z camera axes: OpenGL/NeRF (y up, z backward) <-> OpenCV.
_FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


def quaternion_to_rotation(qvec: np.ndarray) -> np.ndarray:
    """(3, 3) rotation from a quaternion (4,) ordered (w, x, y, z) as COLMAP writes it; normalised
    first because text files round the components (`quaternion_deviation` says by how much)."""
    w, x, y, z = np.asarray(qvec, dtype=np.float64) / np.linalg.norm(qvec)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def quaternion_deviation(qvec: np.ndarray) -> float:
    """How far a quaternion (4,) is from unit length, as | |q|^2 - 1 |: that is max |M^T M - I| of
    the rotation scaled by |q|, so one ROTATION_TOLERANCE serves quaternions and matrices alike
    (inf for a non-finite quaternion)."""
    q = np.asarray(qvec, dtype=np.float64)
    return abs(float(q @ q) - 1.0) if np.all(np.isfinite(q)) else float("inf")


def camera_to_world_from_world_to_camera(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world from a world-to-camera rotation R (3, 3) and translation t (3,):
    x_cam = R x_world + t  =>  x_world = R^T x_cam - R^T t."""
    pose = np.eye(4)
    pose[:3, :3] = R.T
    pose[:3, 3] = -R.T @ np.asarray(t, dtype=np.float64)
    return pose


def opengl_to_opencv(pose: np.ndarray) -> np.ndarray:
    """Camera-to-world (4, 4) with OpenGL camera axes -> OpenCV camera axes (flip y and z columns)."""
    return np.asarray(pose, dtype=np.float64) @ _FLIP_YZ


def parse_pose(matrix: object) -> np.ndarray:
    """(4, 4) float64 from a 4x4 or 3x4 nested list/array (a 3x4 gets the row 0 0 0 1).

    Raises ValueError when the shape is wrong or entries are not numbers; callers turn that into a
    message naming the file.
    """
    array = np.asarray(matrix, dtype=np.float64)
    if array.shape == (3, 4):
        array = np.vstack([array, [0.0, 0.0, 0.0, 1.0]])
    if array.shape != (4, 4):
        raise ValueError(f"expected a 4x4 matrix, got shape {array.shape}")
    return array


# How far from orthonormal a pose's rotation may be, as max |R^T R - I|, and still be used after
# projection to the nearest rotation. Real trackers store rotations with a few significant digits
# (an RGB-D tracker's transforms.json: 1e-4, determinant 0.99986); 1e-2 is about 0.3 degrees of shear,
# well above rounding and well below a scaled or sheared matrix (a file in another convention, a
# pose multiplied by a scale), which warps the reconstruction and is refused.
ROTATION_TOLERANCE = 1e-2
# Deviations below this are the rounding of a text file with 6-7 decimals (ScanNet pose files): they
# are repaired silently; above it the capture gets a warning naming its worst frame.
ROTATION_ROUNDING = 1e-5
# max |R^T R - I| of a rotation computed in float64 (products of a few rotations, quaternion conversions).
_FLOAT_ROUNDING = 1e-12


def rotation_deviation(rotation: np.ndarray) -> float:
    """max |R^T R - I| of a (3, 3) matrix: 0 for a rotation (or a reflection)."""
    R = np.asarray(rotation, dtype=np.float64)
    return float(np.max(np.abs(R.T @ R - np.eye(3))))


def nearest_rotation(matrix: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) closest to `matrix` (3, 3) in the Frobenius norm: U V^T of its SVD, with
    the sign of the last singular direction flipped when U V^T would be a reflection."""
    U, _, Vt = np.linalg.svd(np.asarray(matrix, dtype=np.float64))
    if np.linalg.det(U @ Vt) < 0:
        U[:, -1] = -U[:, -1]
    return U @ Vt


def rigid_pose(pose: np.ndarray, deviation: Optional[float] = None) -> tuple[np.ndarray, float]:
    """A (4, 4) camera-to-world pose made rigid: its rotation projected to the nearest rotation, its
    last row set to (0, 0, 0, 1). Returns the repaired pose and its rotation's deviation from
    orthonormal (max |R^T R - I|, or `deviation` when the caller measured it, e.g. a quaternion's).

    Raises ValueError saying why the pose cannot be used: non-finite values, a last row that is not
    (0, 0, 0, 1), a reflection (determinant < 0), or a deviation above ROTATION_TOLERANCE (a scaled
    or sheared matrix), with the deviation and the tolerance in the message.
    """
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"expected a 4x4 matrix, got shape {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise ValueError("non-finite values (inf/NaN)")
    if np.max(np.abs(pose[3] - [0.0, 0.0, 0.0, 1.0])) > ROTATION_TOLERANCE:
        raise ValueError(f"last row is {pose[3].tolist()}, not [0, 0, 0, 1]")
    rotation = pose[:3, :3]
    if deviation is None:
        deviation = rotation_deviation(rotation)
    determinant = float(np.linalg.det(rotation))
    if determinant <= 0:
        raise ValueError(f"not a rotation: a reflection or degenerate matrix (determinant {determinant:.3g})")
    if deviation > ROTATION_TOLERANCE:
        raise ValueError(f"not a rotation: |R^T R - I| = {deviation:.2g} (determinant {determinant:.4g}), more "
                         f"than the {ROTATION_TOLERANCE:g} tolerated; a scaled or sheared matrix")
    repaired = np.eye(4)
    # A rotation exact to float64 rounding is kept bit for bit, so files our own writers round-trip
    # (%.17g) load back unchanged.
    repaired[:3, :3] = rotation if deviation <= _FLOAT_ROUNDING else nearest_rotation(rotation)
    repaired[:3, 3] = pose[:3, 3]
    return repaired, deviation


class PoseRepairs:
    """The near-rotations one capture's loader made rigid, for one warning naming the worst frame.

    Loaders call `make_rigid` for every pose they read (the single place where poses from files are
    checked, so the CLI, Blender and the batch script see the same poses) and add `warning()` to the
    capture's warnings.
    """

    def __init__(self) -> None:
        self.total = 0
        self.repaired: list[tuple[str, float]] = []  # (frame label, deviation) above ROTATION_ROUNDING

    def make_rigid(self, pose: np.ndarray, label: str, deviation: Optional[float] = None) -> np.ndarray:
        """`rigid_pose(pose)`, remembering `label` when it was off by more than rounding. Raises
        ValueError (see rigid_pose) for a pose that cannot be used."""
        rigid, deviation = rigid_pose(pose, deviation)
        self.total += 1
        if deviation > ROTATION_ROUNDING:
            self.repaired.append((label, deviation))
        return rigid

    def warning(self) -> Optional[str]:
        """"12 of 200 poses were not exactly rotations (worst: ...)", or None when none was."""
        if not self.repaired:
            return None
        label, worst = max(self.repaired, key=lambda item: item[1])
        return (f"{len(self.repaired)} of {self.total} poses were not exactly rotations (worst: {label}, "
                f"|R^T R - I| = {worst:.2g}); they were made orthonormal")


def pinhole(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """K (3, 3) float64."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def fit_intrinsics(K: np.ndarray, stated_size: tuple[int, int], image_size: tuple[int, int],
                   image_path: Path, source: str) -> tuple[np.ndarray, Optional[str]]:
    """K for the image as it is on disk when the capture file states intrinsics for another size.

    Same size: K unchanged. Uniformly scaled (downsampled copies, e.g. nerfstudio images_2/): K is
    scaled and a warning returned. Different aspect ratio: UnusableImage (the intrinsics cannot be
    trusted; loaders skip the photo). Sizes are (width, height).
    """
    (sw, sh), (iw, ih) = stated_size, image_size
    if (sw, sh) == (iw, ih):
        return K, None
    sx, sy = iw / sw, ih / sh
    if abs(sx - sy) <= 0.01 * max(sx, sy):
        scaled = K.copy()
        scaled[0, :] *= sx
        scaled[1, :] *= sy
        return scaled, (f"{source} states a {sw} x {sh} camera but the images are {iw} x {ih} "
                        f"(e.g. {image_path.name}): intrinsics scaled by {sx:.4g}")
    if (sw, sh) == (ih, iw):
        advice = ("the photo looks rotated: it probably has an EXIF orientation tag that the tool which "
                  "wrote the intrinsics ignored; strip the tag (e.g. `exiftool -Orientation= FILE`) and reload")
    else:
        advice = "use the images the intrinsics were computed for"
    raise UnusableImage(image_path, f"{iw} x {ih}, while {source} states a {sw} x {sh} camera "
                                          "(a different aspect ratio)", advice)
