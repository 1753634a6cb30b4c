"""A UV atlas for a result mesh with xatlas (the library Blender's and Godot's lightmappers build on).

xatlas cuts the surface into charts of low distortion, flattens each and packs them into one square;
vertices on a cut are split, so the atlas mesh has more vertices than its source and records which
source vertex each one copies.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import VortxError


@dataclass
class Atlas:
    """source_vertex (V', ) int64: the input vertex each atlas vertex copies; faces (F, 3) int32 into the
    atlas vertices, in the input's face order; uvs (V', 2) float32 in [0, 1], v up (OBJ / Blender);
    charts: how many charts xatlas made; utilisation: the share of the square the charts cover."""

    source_vertex: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    charts: int
    utilisation: float


def uv_atlas(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None, texture_size: int,
             padding: int) -> Atlas:
    """Charts and packing for a `texture_size` square with `padding` texels between charts.

    vertices (V, 3); faces (F, 3); normals (V, 3) or None (they guide the chart cuts).
    """
    import xatlas

    if len(faces) == 0:
        raise VortxError("the mesh has no faces, so there is nothing to texture")
    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(faces, np.uint32),
                   None if normals is None else np.ascontiguousarray(normals, np.float32))
    pack = xatlas.PackOptions()
    pack.resolution = int(texture_size)
    pack.padding = int(padding)
    pack.bilinear = True  # leave room for bilinear filtering at chart borders
    pack.blockAlign = True
    atlas.generate(xatlas.ChartOptions(), pack)
    source_vertex, atlas_faces, uvs = atlas[0]
    if len(atlas_faces) != len(faces):
        raise VortxError(f"the UV atlas lost faces ({len(atlas_faces)} of {len(faces)}); the mesh may be degenerate")
    return Atlas(
        source_vertex=source_vertex.astype(np.int64),
        faces=atlas_faces.astype(np.int32),
        uvs=np.clip(uvs, 0.0, 1.0).astype(np.float32),
        charts=int(atlas.chart_count),
        utilisation=float(atlas.utilization),
    )
