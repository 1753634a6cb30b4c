"""Camera pose and intrinsics conversions used at the edges, when a file's convention is read.

The engine's convention: pose = camera-to-world (4, 4) float64 with OpenCV camera axes
(x right, y down, z forward); K (3, 3) float64 in pixels, pixel (0, 0) covering [0, 1)^2.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..errors import CaptureError

# Diagonal that flips the y and z camera axes: OpenGL/NeRF (y up, z backward) <-> OpenCV.
_FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


def quaternion_to_rotation(qvec: np.ndarray) -> np.ndarray:
    """(3, 3) rotation from a quaternion (4,) ordered (w, x, y, z) as COLMAP writes it; normalised
    first because text files round the components."""
    w, x, y, z = np.asarray(qvec, dtype=np.float64) / np.linalg.norm(qvec)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


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


def pose_problem(pose: np.ndarray) -> Optional[str]:
    """Why a (4, 4) camera-to-world cannot be used ("non-finite values", "not a rotation"), or None.

    Loaders skip such frames with a warning: ScanNet's exporter writes -inf matrices where tracking
    was lost, and a scaled or degenerate rotation would silently warp the reconstruction.
    """
    if not np.all(np.isfinite(pose)):
        return "non-finite values (inf/NaN)"
    det = float(np.linalg.det(pose[:3, :3]))
    if not 0.9 < det < 1.1:
        return f"not a rotation (determinant {det:.3g})"
    return None


def pinhole(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """K (3, 3) float64."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def fit_intrinsics(K: np.ndarray, stated_size: tuple[int, int], image_size: tuple[int, int],
                   image_name: str, source: str) -> tuple[np.ndarray, Optional[str]]:
    """K for the image as it is on disk when the capture file states intrinsics for another size.

    Same size: K unchanged. Uniformly scaled (downsampled copies, e.g. nerfstudio images_2/): K is
    scaled and a warning returned. Different aspect ratio: CaptureError (the intrinsics cannot be
    trusted). Sizes are (width, height).
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
                        f"(e.g. {image_name}): intrinsics scaled by {sx:.4g}")
    if (sw, sh) == (ih, iw):
        hint = (" The photo looks rotated: it probably has an EXIF orientation tag that the tool which "
                "wrote the intrinsics ignored; strip the tag (e.g. `exiftool -Orientation= FILE`) and reload.")
    else:
        hint = " Use the images the intrinsics were computed for."
    raise CaptureError(f"{source} states a {sw} x {sh} camera but image {image_name} is {iw} x {ih} "
                       f"(a different aspect ratio).{hint}")
