"""Camera poses: structure from motion with pycolmap (in a subprocess), gravity and metric scale
(floor plane, camera height, known distances), refinement of given poses, and similarity tools to
compare trajectories."""

from .align import Similarity, fit_pose_similarity, pose_errors, rotation_angle_deg, umeyama
from .floor import FloorPlane, FloorSearch, find_floor_plane
from .gravity import Alignment, KnownDistance, Rescaled, align_gravity_and_scale, rescale_capture, scale_from_known_distance
from .refine import FrameChange, RefineOptions, RefineResult, refine_poses
from .sfm import PoseResult, SfmOptions, choose_matcher, estimate_poses

__all__ = [
    "Alignment",
    "FloorPlane",
    "FloorSearch",
    "FrameChange",
    "KnownDistance",
    "PoseResult",
    "RefineOptions",
    "RefineResult",
    "Rescaled",
    "SfmOptions",
    "Similarity",
    "align_gravity_and_scale",
    "choose_matcher",
    "estimate_poses",
    "find_floor_plane",
    "fit_pose_similarity",
    "pose_errors",
    "refine_poses",
    "rescale_capture",
    "rotation_angle_deg",
    "scale_from_known_distance",
    "umeyama",
]
