"""Colour renders of a mesh from a posed camera, in numpy: what a textured or vertex-coloured result
looks like from a photo's viewpoint, to compare with that photo (engine/eval/texture_views.py).

`render_surface` finds, per pixel, the nearest triangle with the point samples of the depth renderer
(`engine.geometry.depth_render.lattice_samples`: one home for the sampling), then intersects the
pixel centre's ray with that triangle's plane, so barycentrics (and the UVs and colours they
interpolate) are perspective-correct. Pixel convention: pixel (row i, column j) covers u in
[j, j + 1), v in [i, i + 1), its centre at (j + 0.5, i + 0.5) (engine/geometry/cameras.py).

Big triangles are sampled at up to SURFACE_MAX_EDGE_SAMPLES steps per edge (a 2-triangle quad filling
a test image renders without holes); triangles crossing the near plane are skipped, as in
`render_depth`, so split coarse meshes (`engine.meshops.subdivide`) before rendering them from inside.
"""

from __future__ import annotations

import numpy as np

from ..errors import VortxError
from ..geometry.cameras import world_to_camera
from ..geometry.depth_render import lattice_samples
from ..mesh_io import Mesh
from ..photo_sampling import sample_bilinear
from ..texture.textured_mesh import TexturedMesh

SURFACE_MAX_EDGE_SAMPLES = 1024  # a triangle 512 pixels across still gets half-pixel sample spacing


def render_surface(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, pose: np.ndarray, size: tuple[int, int],
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which triangle each pixel shows, where on it, and how far: (face_id, bary, depth).

    vertices (V, 3) world; faces (F, 3); K (3, 3) pixels; pose (4, 4) camera-to-world (OpenCV axes);
    size = (w, h). face_id (h, w) int64, -1 for background; bary (h, w, 3) float32: barycentric
    coordinates of the pixel centre's ray on that triangle (clipped to the triangle at its rim, where
    a pixel the triangle overlaps has its centre just outside); depth (h, w) float32 planar camera
    depth of that point, inf for background.
    """
    w, h = size
    faces = np.asarray(faces, np.int64)
    best_z = np.full(h * w, np.inf)
    best_face = np.full(h * w, -1, np.int64)
    for chunk in lattice_samples(vertices, faces, K, pose, size, max_edge_samples=SURFACE_MAX_EDGE_SAMPLES):
        flat = chunk.flat[chunk.inside]
        z = chunk.points[chunk.inside, 2]
        face = np.repeat(chunk.faces, chunk.samples)[chunk.inside]
        # The nearest sample of this chunk per pixel, then the z-buffer test against earlier chunks.
        order = np.lexsort((z, flat))
        flat, z, face = flat[order], z[order], face[order]
        first = np.ones(len(flat), bool)
        first[1:] = flat[1:] != flat[:-1]
        flat, z, face = flat[first], z[first], face[first]
        nearer = z < best_z[flat]
        best_z[flat[nearer]] = z[nearer]
        best_face[flat[nearer]] = face[nearer]
    bary = np.zeros((h * w, 3), np.float32)
    depth = np.full(h * w, np.inf, np.float32)
    hit = np.flatnonzero(best_face >= 0)
    if len(hit):
        corners = world_to_camera(np.asarray(vertices, np.float64), pose)[faces[best_face[hit]]]  # (N, 3, 3)
        rows, cols = np.divmod(hit, w)
        ray = np.linalg.solve(np.asarray(K, np.float64), np.stack([cols + 0.5, rows + 0.5, np.ones(len(hit))]))  # (3, N)
        b = _ray_barycentrics(corners, ray.T)
        bary[hit] = b
        depth[hit] = np.einsum("nk,nk->n", b.astype(np.float64), corners[:, :, 2])
    return best_face.reshape(h, w), bary.reshape(h, w, 3), depth.reshape(h, w)


def _ray_barycentrics(corners: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """(N, 3) float32 barycentrics where rays (N, 3) from the camera centre meet the planes of
    triangles (N, 3, 3) (camera coordinates), clipped to the triangle and renormalised."""
    a, e1, e2 = corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    # a + b1 e1 + b2 e2 = t ray  <=>  [e1 e2 -ray] (b1, b2, t) = -a, solved by Cramer's rule.
    normal = np.cross(e1, e2)
    det = -np.einsum("nk,nk->n", normal, rays)
    safe = np.where(np.abs(det) > 1e-15, det, np.inf)  # edge-on triangles: fall back to the centroid below
    b1 = np.einsum("nk,nk->n", np.cross(-a, e2), -rays) / safe
    b2 = np.einsum("nk,nk->n", np.cross(e1, -a), -rays) / safe
    b = np.clip(np.stack([1.0 - b1 - b2, b1, b2], axis=1), 0.0, 1.0)
    total = b.sum(axis=1, keepdims=True)
    b = np.where(np.isfinite(safe)[:, None] & (total > 0), b / np.where(total > 0, total, 1.0), 1.0 / 3.0)
    return b.astype(np.float32)


def render_textured(textured: TexturedMesh, K: np.ndarray, pose: np.ndarray, size: tuple[int, int],
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The textured mesh seen from a camera: (image (h, w, 3) uint8 sRGB, mask (h, w) bool of the
    pixels it covers; background black).

    Per pixel the UV is interpolated with perspective-correct barycentrics and the texture sampled
    bilinearly (edge-clamped) in its sRGB bytes; texel (row r, column c) has its centre at
    u = (c + 0.5) / W, v = 1 - (r + 0.5) / H (TexturedMesh's convention). No mipmaps: the held-out
    photos see the surface at about the texture's resolution or coarser, where a viewer's mipmaps
    would blur as the photo's own pixels do.
    """
    face_id, bary, _ = render_surface(textured.vertices, textured.faces, K, pose, size)
    mask = face_id >= 0
    w, h = size
    image = np.zeros((h, w, 3), np.uint8)
    if mask.any():
        uvs = np.asarray(textured.uvs, np.float64)[np.asarray(textured.faces, np.int64)[face_id[mask]]]  # (N, 3, 2)
        uv = np.einsum("nk,nkc->nc", bary[mask].astype(np.float64), uvs)
        tw, th = textured.texture_size
        colour = sample_bilinear(np.ascontiguousarray(textured.texture), uv[:, 0] * tw, (1.0 - uv[:, 1]) * th)
        image[mask] = np.clip(np.round(colour), 0, 255).astype(np.uint8)
    return image, mask


def render_vertex_colours(mesh: Mesh, K: np.ndarray, pose: np.ndarray, size: tuple[int, int],
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's vertex colours (sRGB 0..1, interpolated across each triangle as a viewer shades
    them, without lighting) seen from a camera: (image (h, w, 3) uint8, mask (h, w) bool)."""
    if mesh.colors is None:
        raise VortxError("the mesh has no vertex colours to render")
    face_id, bary, _ = render_surface(mesh.vertices, mesh.faces, K, pose, size)
    mask = face_id >= 0
    w, h = size
    image = np.zeros((h, w, 3), np.uint8)
    if mask.any():
        colours = np.asarray(mesh.colors, np.float64)[np.asarray(mesh.faces, np.int64)[face_id[mask]]]  # (N, 3, 3)
        image[mask] = np.clip(np.round(255 * np.einsum("nk,nkc->nc", bary[mask].astype(np.float64), colours)),
                              0, 255).astype(np.uint8)
    return image, mask
