"""The finishing stage in a reconstruction (the `finish` setting): between marching cubes and the
vertex colours, so colours, the confidence layer and every file describe the finished mesh.

Both methods call it: the stereo method with its depth maps as the free-space evidence, VoRTX with its
stereo depth maps when its weights take them, otherwise the mesh's own depth from the keyframes
(engine/finish/free_space.py `mesh_depth_views`).
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np

from ..finish.finishing import finish_mesh
from ..finish.modes import FINISH_OFF
from ..finish.free_space import DepthView, mesh_depth_views
from ..mesh_io import Mesh
from .plan import ReconPlan
from .settings import ReconSettings

MESH_VIEWS = 40  # keyframes whose render of the mesh stands in for depth maps (a method without any)


def finish_reconstruction(mesh: Mesh, plan: ReconPlan, settings: ReconSettings,
                          views: Optional[Sequence[DepthView]] = None) -> tuple[Mesh, Optional[dict[str, Any]]]:
    """(the finished mesh, the stage's stats) of a run's marching-cubes `mesh`; the mesh as it is and
    None when `settings.finish` is off or the mesh is empty. views: the run's depth maps, or None."""
    if settings.finish == FINISH_OFF or len(mesh.faces) == 0:
        return mesh, None
    if not views:  # the mesh's own depth from (evenly spaced) keyframes: each is a render of the mesh
        chosen = np.unique(np.round(np.linspace(0, len(plan.keyframes) - 1, min(MESH_VIEWS, len(plan.keyframes)))).astype(int))
        views = [view for k in chosen
                 for view in mesh_depth_views(mesh, plan.Ks[k:k + 1], plan.poses[k:k + 1],
                                              (int(plan.sizes[k][0]), int(plan.sizes[k][1])))]
    result = finish_mesh(mesh, views, plan.poses[:, :3, 3], settings.voxel_size, settings.finish)
    return result.mesh, result.stats
