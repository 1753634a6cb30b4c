"""How well each mesh vertex was observed: the confidence layer an artist reads to see where to take
more photos (issue 11.6).

Per vertex, from the stereo depth maps of the run:
- `observations`: how many depth maps saw the vertex at their depth: it projects into the view in
  front of the camera, the view has a depth there, and the vertex lies within the TSDF truncation of
  that depth. A depth much nearer than the vertex means the view was occluded there; one much
  farther means the view saw through where the vertex is; neither counts.
- `stereo_confidence`: the mean stereo confidence (aggregated NCC) of those observations, 0 when none.
- `completed`: 1 where the surface was not observed but completed by the network, 0 where observed.
  Classical stereo fusion only meshes what depth maps saw, so it is always 0 there; for VoRTX it is 1
  where no depth map sees the vertex.

The same pixel rule as the TSDF fusion that built the surface (engine/tsdf/integration.py): a camera
point projects to the pixel that contains K @ x_cam (floor), pixel (0, 0) covering [0, 1)^2; the
projection is the photo lookups' own (`engine.photo_sampling.points_in_view`).
The names and the colour an artist sees live in engine/observation.py (numpy only, for Blender).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..mesh_io import Mesh
from ..observation import COMPLETED, OBSERVATIONS, STEREO_CONFIDENCE
from ..photo_sampling import points_in_view
from .depth_maps import DepthMap
from .fused_tsdf import TRUNCATION_VOXELS

def observe_vertices(vertices: np.ndarray, maps: Sequence[DepthMap], truncation: float) -> tuple[np.ndarray, np.ndarray]:
    """(observations (V,) float32, stereo_confidence (V,) float32) of world-space `vertices` (V, 3).

    truncation: metres; a view observes a vertex when |depth at its pixel - its depth| <= truncation
    (use the TSDF truncation the surface was fused with).
    """
    if truncation <= 0:
        raise ValueError(f"truncation must be positive, got {truncation}")
    points = np.asarray(vertices, np.float64).reshape(-1, 3)
    count = np.zeros(len(points), np.float32)
    confidence_sum = np.zeros(len(points), np.float32)
    for depth_map in maps:
        height, width = depth_map.depth.shape
        ids, u, v, z = points_in_view(points, depth_map.K, depth_map.pose, (width, height))
        row, col = np.floor(v).astype(np.int64), np.floor(u).astype(np.int64)
        seen_depth = depth_map.depth[row, col]
        seen = (seen_depth > 0) & (np.abs(seen_depth - z) <= truncation)
        count[ids[seen]] += 1
        confidence_sum[ids[seen]] += depth_map.confidence[row[seen], col[seen]]
    mean_confidence = np.where(count > 0, confidence_sum / np.maximum(count, 1), 0).astype(np.float32)
    return count, mean_confidence


def vertex_evidence(
    vertices: np.ndarray,
    maps: Sequence[DepthMap],
    truncation: float,
    network_completes: bool,
) -> dict[str, np.ndarray]:
    """The evidence attributes of a mesh's vertices (V, 3): name -> (V,) float32 (see module doc).

    network_completes: True for a network's surface (unobserved vertices are `completed`), False for
    classical fusion, which places surface only where depth maps put it (`completed` is 0).
    """
    observations, confidence = observe_vertices(vertices, maps, truncation)
    completed = (observations == 0) if network_completes else np.zeros(len(observations), bool)
    return {OBSERVATIONS: observations, STEREO_CONFIDENCE: confidence, COMPLETED: completed.astype(np.float32)}


def attach_evidence(
    mesh: Mesh, maps: Sequence[DepthMap], voxel_size: float, network_completes: bool,
    truncation_voxels: float = TRUNCATION_VOXELS,
) -> dict[str, float]:
    """Set `mesh.attributes` to the evidence of its vertices from `maps`, judged within the TSDF truncation
    the surface was fused with (`truncation_voxels` voxels of `voxel_size`; 3 as the ground truth and the
    network's stereo TSDF); returns `evidence_summary`."""
    mesh.attributes = {**mesh.attributes, **vertex_evidence(mesh.vertices, maps, truncation_voxels * voxel_size,
                                                             network_completes)}
    return evidence_summary(mesh.attributes)


def evidence_summary(attributes: dict[str, np.ndarray]) -> dict[str, float]:
    """Share of vertices seen by none, 1-2 and >= 3 depth maps, the mean confidence of the seen ones and
    the completed share: the numbers a run's stats report."""
    observations = np.asarray(attributes[OBSERVATIONS])
    if len(observations) == 0:
        return {"unobserved": 0.0, "seen_by_1_2": 0.0, "seen_by_3_plus": 0.0, "confidence_mean": 0.0, "completed": 0.0}
    seen = observations > 0
    confidence = np.asarray(attributes[STEREO_CONFIDENCE])
    return {
        "unobserved": round(float(np.mean(~seen)), 4),
        "seen_by_1_2": round(float(np.mean(seen & (observations < 3))), 4),
        "seen_by_3_plus": round(float(np.mean(observations >= 3)), 4),
        "confidence_mean": round(float(confidence[seen].mean()) if seen.any() else 0.0, 4),
        "completed": round(float(np.mean(np.asarray(attributes[COMPLETED]) > 0.5)), 4),
    }
