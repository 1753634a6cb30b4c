"""Camera poses: structure from motion with pycolmap (in a subprocess), gravity and metric scale,
and similarity tools to compare trajectories."""

from .align import Similarity, pose_errors, rotation_angle_deg, umeyama
from .gravity import Alignment, KnownDistance, align_gravity_and_scale
from .sfm import PoseResult, SfmOptions, choose_matcher, estimate_poses

__all__ = [
    "Alignment",
    "KnownDistance",
    "PoseResult",
    "SfmOptions",
    "Similarity",
    "align_gravity_and_scale",
    "choose_matcher",
    "estimate_poses",
    "pose_errors",
    "rotation_angle_deg",
    "umeyama",
]
