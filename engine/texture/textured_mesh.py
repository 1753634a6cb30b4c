"""A mesh with one UV set and one base-colour texture: what the bake makes and the writers write."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..mesh_io import Mesh


@dataclass
class TexturedMesh:
    """vertices (V, 3) float32 world metres, Z up; faces (F, 3) int32; normals (V, 3) float32;
    uvs (V, 2) float32 in [0, 1], u to the right and v *up* from the texture's bottom row (the OBJ and
    Blender convention; glTF's top-left origin is the writer's business);
    texture (H, W, 3) uint8 sRGB, row 0 at the top (v = 1), as PNG stores it;
    colors (V, 3) float32 0..1 sRGB vertex colours (kept so the PLY and the confidence view still work);
    attributes: name -> (V,) float32 per-vertex values (the confidence layer);
    source_vertex (V,) int64: the vertex of the untextured mesh each vertex copies (atlas seams split
    vertices, so V >= the source's vertex count).
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    texture: np.ndarray
    colors: Optional[np.ndarray] = None
    attributes: dict[str, np.ndarray] = field(default_factory=dict)
    source_vertex: Optional[np.ndarray] = None

    @property
    def texture_size(self) -> tuple[int, int]:
        """(width, height) in texels."""
        return int(self.texture.shape[1]), int(self.texture.shape[0])

    def untextured(self) -> Mesh:
        """The same surface as a plain Mesh (vertex colours, attributes), e.g. for a PLY."""
        return Mesh(vertices=self.vertices, faces=self.faces, normals=self.normals, colors=self.colors,
                    attributes=dict(self.attributes))
