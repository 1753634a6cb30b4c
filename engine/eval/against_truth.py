"""A reconstruction from photos alone scored against a capture's truth (the demo, scripts/demo.py):
structure from motion knows the world only up to a similarity, so the estimated cameras are fitted to
the true ones (Sim(3) of the camera centres), the poses compared after that fit, and each mesh moved
into the truth frame by the same similarity before it is scored."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..mesh_io import Mesh
from ..poses import Similarity, pose_errors, umeyama
from ..tsdf.volume import TsdfVolume
from .mesh_metrics import MeshMetrics, evaluate_mesh
from .surface_metrics import SurfaceMetrics, evaluate_surface


def true_poses(truth: Path, stems: Sequence[str]) -> dict[str, np.ndarray]:
    """{photo stem: camera-to-world} from truth/pose/<stem>.txt, for the stems that have one."""
    return {s: np.loadtxt(truth / "pose" / f"{s}.txt").reshape(4, 4) for s in stems if (truth / "pose" / f"{s}.txt").is_file()}


@dataclass
class PoseComparison:
    """Estimated cameras against the true ones of the same photos."""

    stems: list[str]  # the photos with both an estimated and a true pose
    errors: dict[str, float]  # engine.poses.pose_errors: rotation_deg_mean/max, position_mean/max (metres), up_deg
    to_truth: Similarity  # estimated world -> truth world, from the camera centres

    def summary(self, total: int) -> str:
        """One line: how many of `total` photos were registered, the fit's scale and the errors."""
        return (f"poses vs truth ({len(self.stems)} of {total} photos registered; after the Sim(3) fit of the camera "
                f"centres, scale {self.to_truth.scale:.3f}): rotation error mean {self.errors['rotation_deg_mean']:.2f} deg "
                f"(max {self.errors['rotation_deg_max']:.2f}), position error mean {100 * self.errors['position_mean']:.1f} cm "
                f"(max {100 * self.errors['position_max']:.1f} cm), up off by {self.errors['up_deg']:.2f} deg")


def compare_poses(estimated: Mapping[str, np.ndarray], truths: Mapping[str, np.ndarray]) -> PoseComparison:
    """The photos in both, their pose errors and the similarity that maps the estimated camera centres
    onto the true ones (the same fit pose_errors makes). Needs 3 photos in both."""
    stems = sorted(set(estimated) & set(truths))
    errors = pose_errors([estimated[s] for s in stems], [truths[s] for s in stems])
    to_truth = umeyama(np.array([estimated[s][:3, 3] for s in stems]), np.array([truths[s][:3, 3] for s in stems]))
    return PoseComparison(stems, errors, to_truth)


@dataclass
class ScoredMesh:
    name: str
    mesh: MeshMetrics  # Atlas metrics: F-score, precision, recall, accuracy, completeness (5 cm threshold)
    surface: SurfaceMetrics  # normal agreement, floaters, pieces, area ratio, open boundary


def score_mesh(name: str, mesh: Mesh, truth: Mesh, truth_volume: TsdfVolume) -> ScoredMesh:
    """`mesh` (already in the truth frame) against the true mesh, trimmed to the space the truth TSDF observed."""
    return ScoredMesh(name, evaluate_mesh(mesh, truth, truth_volume), evaluate_surface(mesh, truth, truth_volume))


def fscore_table(rows: Sequence[ScoredMesh]) -> list[str]:
    """The F-score table's lines: a header, then one line per mesh."""
    lines = [f"{'method':<48} {'F':>6} {'prec':>6} {'recall':>6} {'acc cm':>7} {'comp cm':>8}"]
    for row in rows:
        m = row.mesh
        lines.append(f"{row.name:<48} {m.fscore:6.3f} {m.prec:6.3f} {m.recall:6.3f} {100 * m.acc:7.1f} {100 * m.comp:8.1f}")
    return lines
