"""Evidence-weighted fusion of stereo depth: a surface several views agree on is meshed, a patch that
one view alone reports is not, and mesh pieces go by how many views support them, not by size."""

from __future__ import annotations

import numpy as np

from engine.geometry.cameras import look_at
from engine.recon.mesh import extract_mesh
from engine.stereo.depth_maps import DepthMap
from engine.stereo.fused_tsdf import fuse_depth_maps
from engine.stereo.fused_tsdf import drop_unsupported_pieces, fuse_stereo_evidence, vertex_support

VOXEL = 0.04
W, H = 64, 48
K = np.array([[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]])


def wall_maps(floater: bool) -> list[DepthMap]:
    """Three cameras 0.3 m apart looking along +y at a wall 2 m ahead; the first also reports a
    0.5 m-deep patch of matching noise in a corner of its view that the others do not see."""
    maps = []
    for i, x in enumerate((-0.3, 0.0, 0.3)):
        eye = np.array([x, 0.0, 1.2])
        pose = look_at(eye, eye + np.array([0.0, 1.0, 0.0]))
        depth = np.full((H, W), 2.0, np.float32)
        if floater and i == 0:
            depth[2:14, 2:14] = 0.5
        maps.append(DepthMap(i, depth, np.full((H, W), 0.9, np.float32), K, pose, np.array([], np.int64), (0.3, 4.0)))
    return maps


def grid():
    origin = np.array([-2.0, -0.2, -0.6])
    return origin, (100, 70, 70)


def faces_near_the_camera(mesh) -> int:
    return int((mesh.vertices[mesh.faces].mean(axis=1)[:, 1] < 1.0).sum()) if len(mesh.faces) else 0


def test_a_patch_one_view_reports_is_not_meshed_and_the_wall_is() -> None:
    origin, dims = grid()
    maps = wall_maps(floater=True)
    plain, weight = fuse_depth_maps(maps, origin, dims, VOXEL, 4.0)
    plain_mesh = extract_mesh(np.argwhere(weight > 0), plain[weight > 0], origin, VOXEL)
    assert faces_near_the_camera(plain_mesh) > 0, "unweighted fusion meshes the one-view patch"

    fused = fuse_stereo_evidence(maps, origin, dims, VOXEL, 4.0)
    wall = tuple(np.round((np.array([0.0, 0.8 + 1.2, 1.2]) - origin) / VOXEL).astype(int))  # world (0, 2, 1.2)
    assert fused.support[wall] == 3
    keep = fused.surface_voxels(min_support=2)
    mesh = extract_mesh(np.argwhere(keep), fused.tsdf[keep], origin, VOXEL)
    assert faces_near_the_camera(mesh) == 0
    wall_faces = np.abs(mesh.vertices[mesh.faces].mean(axis=1)[:, 1] - 2.0) < 0.05
    assert wall_faces.sum() > 100, "the wall all three views see is meshed"


def test_pieces_go_by_the_views_that_support_them() -> None:
    origin, dims = grid()
    maps = wall_maps(floater=True)
    fused = fuse_stereo_evidence(maps, origin, dims, VOXEL, 4.0)
    observed = fused.observations > 0
    mesh = extract_mesh(np.argwhere(observed), fused.tsdf[observed], origin, VOXEL)
    assert faces_near_the_camera(mesh) > 0
    kept, stats = drop_unsupported_pieces(mesh, vertex_support(mesh, fused.support, origin, VOXEL), min_views=2)
    assert faces_near_the_camera(kept) == 0
    assert stats["dropped_pieces"] >= 1 and len(kept.faces) > 100


def test_evidence_fusion_of_agreeing_views_matches_plain_fusion_on_the_surface() -> None:
    origin, dims = grid()
    maps = wall_maps(floater=False)
    plain, weight = fuse_depth_maps(maps, origin, dims, VOXEL, 4.0)
    fused = fuse_stereo_evidence(maps, origin, dims, VOXEL, 4.0)
    both = (weight > 0) & (fused.observations > 0)
    # Same depth in every view: the weights cannot move the zero crossing.
    assert np.abs(plain[both] - fused.tsdf[both]).max() < 1e-4
