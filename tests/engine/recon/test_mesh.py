"""Marching cubes on sparse TSDFs with a known answer, and the mesh's normal direction."""

from __future__ import annotations

import numpy as np

from engine.recon.mesh import extract_mesh

VOXEL = 0.04
ORIGIN = np.array([1.0, -2.0, 0.5])


def sphere_tsdf(radius_vox: float, solid: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sparse voxels in a 3-voxel band around a sphere. solid=True: a ball seen from outside (positive
    inside = behind the surface); solid=False: a spherical room seen from inside (negative inside)."""
    n = int(2 * radius_vox + 10)
    idx = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
    centre_vox = np.array([n / 2 + 0.3, n / 2 - 0.2, n / 2 + 0.1])
    signed = radius_vox - np.linalg.norm(idx - centre_vox, axis=1)  # > 0 inside
    band = np.abs(signed) < 3
    tsdf = np.clip(signed / 3, -1, 1) * (1 if solid else -1)
    return idx[band], tsdf[band], ORIGIN + centre_vox * VOXEL


def test_sphere_vertices_lie_on_the_radius_and_normals_face_free_space():
    for solid in (True, False):
        indices, tsdf, centre = sphere_tsdf(12.0, solid)
        mesh = extract_mesh(indices, tsdf, ORIGIN, VOXEL)
        assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int32
        assert len(mesh.faces) > 500
        radial = mesh.vertices - centre
        radius = np.linalg.norm(radial, axis=1)
        np.testing.assert_allclose(radius, 12.0 * VOXEL, atol=0.1 * VOXEL)
        outward = np.einsum("nd,nd->n", mesh.normals, radial / radius[:, None])
        # Free space is outside a solid ball and inside a room: normals point there.
        if solid:
            assert outward.min() > 0.9
        else:
            assert outward.max() < -0.9
        # Winding agrees with the normals (what Blender uses to shade).
        v = mesh.vertices[mesh.faces]
        face_n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        face_out = np.einsum("nd,nd->n", face_n, v.mean(axis=1) - centre)
        assert np.all(face_out > 0) if solid else np.all(face_out < 0)
        assert mesh.faces.min() >= 0 and mesh.faces.max() < len(mesh.vertices)
        assert np.isfinite(mesh.vertices).all() and np.isfinite(mesh.normals).all()


def test_holes_in_the_sparse_volume_never_make_nan_vertices():
    indices, tsdf, _ = sphere_tsdf(10.0, True)
    rng = np.random.default_rng(0)
    keep = rng.random(len(indices)) > 0.2  # knock out 20 % of the voxels: NaN cells in the dense volume
    mesh = extract_mesh(indices[keep], tsdf[keep], ORIGIN, VOXEL)
    assert len(mesh.faces) > 0 and np.isfinite(mesh.vertices).all()
    full = extract_mesh(indices, tsdf, ORIGIN, VOXEL)
    assert len(mesh.faces) < len(full.faces)


def test_no_zero_crossing_gives_an_empty_mesh():
    idx = np.stack(np.meshgrid(*[np.arange(6)] * 3, indexing="ij"), -1).reshape(-1, 3)
    for value in (-1.0, 0.7):
        mesh = extract_mesh(idx, np.full(len(idx), value), ORIGIN, VOXEL)
        assert mesh.vertices.shape == (0, 3) and mesh.faces.shape == (0, 3)
    assert len(extract_mesh(np.zeros((0, 3), np.int64), np.zeros(0), ORIGIN, VOXEL).faces) == 0
