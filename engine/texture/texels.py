"""Which surface point each texel shows: the atlas triangles rasterised in texture space.

Texel (row r, column c) has its centre at u = (c + 0.5) / W, v = 1 - (r + 0.5) / H (v up, row 0 at the
top). A texel belongs to the triangle whose UV triangle contains its centre; its barycentric
coordinates there give its 3D point and normal. Texels whose centre no triangle contains (chart
borders, gutters) are filled afterwards from their neighbours (`bake.fill_gutters`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

INTERPOLATE_CHUNK = 2_000_000
CANDIDATES_PER_CALL = 4_000_000  # bounds the (triangles, candidate texels) buffers to ~100 MB


@dataclass
class Texels:
    """rows, cols (N,) int32: the covered texels; face (N,) int32: their triangle; bary (N, 3) float32."""

    rows: np.ndarray
    cols: np.ndarray
    face: np.ndarray
    bary: np.ndarray

    def __len__(self) -> int:
        return len(self.rows)

    def interpolate(self, per_vertex: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(N, C) float32: per-vertex values (V, C) at the texels (in chunks: an 8192 px texture has
        ~40 M texels, and the (N, 3, C) corner array at once would take gigabytes)."""
        per_vertex = np.asarray(per_vertex, np.float32)
        out = np.empty((len(self), per_vertex.shape[1]), np.float32)
        for start in range(0, len(self), INTERPOLATE_CHUNK):
            part = slice(start, start + INTERPOLATE_CHUNK)
            corners = per_vertex[faces[self.face[part]]]  # (n, 3, C)
            out[part] = np.einsum("nk,nkc->nc", self.bary[part], corners)
        return out


def rasterise_uv(uvs: np.ndarray, faces: np.ndarray, size: tuple[int, int]) -> Texels:
    """Every texel whose centre lies inside a UV triangle (the first triangle wins where charts touch).

    uvs (V, 2) in [0, 1] (v up); faces (F, 3); size = (W, H). Triangles are grouped by the size of their
    texel bounding box and tested in one array operation per group.
    """
    W, H = size
    tri = uvs[faces].astype(np.float64) * [W, H]  # (F, 3, 2) in texel units, y up
    tri[..., 1] = H - tri[..., 1]  # y down: rows
    low = np.floor(tri.min(axis=1) - 0.5).astype(np.int64)  # first candidate column / row
    high = np.ceil(tri.max(axis=1) - 0.5).astype(np.int64)
    extent = np.maximum(high - low + 1, 1).max(axis=1)
    # Bins of powers of two: few groups, at most 4x wasted candidates.
    bins = 2 ** np.ceil(np.log2(extent)).astype(np.int64)
    covered = np.full(H * W, -1, dtype=np.int32)  # face ids; int32 halves the 8192 px buffer
    bary_image = np.zeros((H * W, 3), dtype=np.float32)
    for n in np.unique(bins):
        group = np.flatnonzero(bins == n)
        dy, dx = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        dx, dy = dx.ravel(), dy.ravel()
        per_call = max(1, CANDIDATES_PER_CALL // (n * n))
        for a in range(0, len(group), per_call):
            ids = group[a:a + per_call]
            cols = low[ids, 0, None] + dx[None]  # (t, n*n)
            rows = low[ids, 1, None] + dy[None]
            px, py = cols + 0.5, rows + 0.5
            t = tri[ids]
            x0, y0 = t[:, 0, 0, None], t[:, 0, 1, None]
            e1x, e1y = t[:, 1, 0, None] - x0, t[:, 1, 1, None] - y0
            e2x, e2y = t[:, 2, 0, None] - x0, t[:, 2, 1, None] - y0
            det = e1x * e2y - e1y * e2x
            safe = np.where(np.abs(det) > 1e-12, det, np.inf)
            qx, qy = px - x0, py - y0
            b1 = (qx * e2y - qy * e2x) / safe
            b2 = (e1x * qy - e1y * qx) / safe
            b0 = 1.0 - b1 - b2
            eps = 1e-7
            inside = (b0 >= -eps) & (b1 >= -eps) & (b2 >= -eps) & (cols >= 0) & (cols < W) & (rows >= 0) & (rows < H)
            inside &= np.isfinite(safe)
            t_idx, s_idx = np.nonzero(inside)
            flat = rows[t_idx, s_idx] * W + cols[t_idx, s_idx]
            free = covered[flat] < 0
            flat, t_idx, s_idx = flat[free], t_idx[free], s_idx[free]
            # Duplicates within one call (shared edges): keep the first.
            flat, first = np.unique(flat, return_index=True)
            t_idx, s_idx = t_idx[first], s_idx[first]
            covered[flat] = ids[t_idx]
            bary_image[flat] = np.stack([b0[t_idx, s_idx], b1[t_idx, s_idx], b2[t_idx, s_idx]], axis=1)
    flat = np.flatnonzero(covered >= 0)
    bary = np.clip(bary_image[flat], 0.0, 1.0)
    bary /= bary.sum(axis=1, keepdims=True)
    return Texels(rows=(flat // W).astype(np.int32), cols=(flat % W).astype(np.int32),
                  face=covered[flat].astype(np.int32), bary=bary.astype(np.float32))
