"""Fusion block by block gives the mesh one whole grid gives: same triangles, vertices welded across
the block seams into one connected surface, evidence carried per vertex; blocks no depth map reaches
are not fused."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from engine.geometry.cameras import look_at
from engine.meshops import face_pieces
from engine.recon.block_fusion import fuse_blocks, fusion_blocks
from engine.stereo.depth_maps import DepthMap
from engine.stereo.fused_tsdf import fuse_stereo_evidence, vertex_support

VOXEL = 0.08
W, H = 80, 60
K = np.array([[60.0, 0, W / 2], [0, 60.0, H / 2], [0, 0, 1]])
ROOM = np.array([6.0, 4.0, 2.6])  # an axis-aligned box room [0, ROOM]


def box_depth(pose: np.ndarray) -> np.ndarray:
    """Planar depth (H, W) of the inside of the box room seen from `pose` (OpenCV camera-to-world)."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    rays = np.linalg.inv(K) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    world = pose[:3, :3] @ rays  # (3, N): direction per unit of camera z
    eye = pose[:3, 3:4]
    with np.errstate(divide="ignore", invalid="ignore"):
        exits = np.where(world > 0, (ROOM[:, None] - eye) / world, np.where(world < 0, -eye / world, np.inf))
    return exits.min(axis=0).reshape(H, W).astype(np.float32)


def room_maps() -> list[DepthMap]:
    """Cameras walking the room's long axis, looking at the walls, the floor and the corners."""
    maps = []
    for i, (x, y, tx, ty, tz) in enumerate([(1.0, 1.0, 6, 4, 0.5), (2.5, 2.0, 0, 4, 1.0), (3.5, 2.0, 6, 0, 0.3),
                                             (5.0, 3.0, 0, 0, 0.8), (3.0, 1.0, 3, 4, 1.5), (4.5, 1.5, 6, 2, 0.0)]):
        eye = np.array([x, y, 1.4])
        pose = look_at(eye, np.array([tx, ty, tz], float))
        depth = box_depth(pose)
        maps.append(DepthMap(i, depth, np.full((H, W), 0.9, np.float32), K, pose, np.array([], np.int64), (0.3, 8.0)))
    return maps


def grid() -> tuple[np.ndarray, tuple[int, int, int]]:
    origin = np.array([-0.32, -0.32, -0.32])
    return origin, tuple(int(d) for d in np.ceil((ROOM + 0.64) / VOXEL) + 1)


def assert_same_triangles(mesh, reference, tolerance: float = 1e-5) -> None:
    """Every triangle of `mesh` is one of `reference`'s, one to one, corners within `tolerance` metres
    (the blocks' marching cubes run on other local coordinates: float32 noise, no more)."""
    assert len(mesh.faces) == len(reference.faces)
    corners = mesh.vertices[mesh.faces].astype(np.float64)  # (F, 3, 3)
    reference_corners = reference.vertices[reference.faces].astype(np.float64)
    distance, match = cKDTree(reference_corners.mean(axis=1)).query(corners.mean(axis=1))
    assert distance.max() < tolerance
    assert len(np.unique(match)) == len(match)
    ordered = np.sort(corners.reshape(len(corners), 9), axis=1)
    np.testing.assert_allclose(ordered, np.sort(reference_corners[match].reshape(len(match), 9), axis=1), atol=tolerance)


@pytest.mark.parametrize("evidence", [False, True])
def test_blocks_give_the_whole_grids_mesh_welded_into_one_surface(evidence: bool) -> None:
    origin, dims = grid()
    maps = room_maps()
    whole = fuse_blocks(maps, origin, dims, VOXEL, 4.0, "cpu", evidence_fusion=evidence, block_voxels=10_000)
    blocks = fuse_blocks(maps, origin, dims, VOXEL, 4.0, "cpu", evidence_fusion=evidence, block_voxels=16)
    assert whole.blocks == 1 and blocks.blocks > 12
    assert len(whole.mesh.faces) > 2000
    assert_same_triangles(blocks.mesh, whole.mesh)
    # Welded: the seams add no vertices and cut the surface into no more pieces than the whole grid's.
    assert len(blocks.mesh.vertices) == len(whole.mesh.vertices)
    assert face_pieces(blocks.mesh.faces, len(blocks.mesh.vertices))[0].max() == \
        face_pieces(whole.mesh.faces, len(whole.mesh.vertices))[0].max()
    if evidence:
        # Per-vertex support as the whole grid's support volume gives it.
        fused = fuse_stereo_evidence(maps, origin, dims, VOXEL, 4.0)
        distance, match = cKDTree(whole.mesh.vertices).query(blocks.mesh.vertices)
        assert distance.max() < 1e-5
        expected = vertex_support(whole.mesh, fused.support, origin, VOXEL)[match]
        np.testing.assert_array_equal(blocks.vertex_support, expected)
        assert expected.max() >= 2


def test_blocks_no_depth_map_reaches_are_not_fused() -> None:
    origin, dims = grid()
    maps = room_maps()
    # The same room with 40 m of empty grid beside it: only the room's blocks are fused.
    wide = (dims[0] + 500, dims[1], dims[2])
    room = fuse_blocks(maps, origin, dims, VOXEL, 4.0, "cpu", block_voxels=32)
    beside = fuse_blocks(maps, origin, wide, VOXEL, 4.0, "cpu", block_voxels=32)
    assert len(fusion_blocks(wide, 32)) >= 4 * beside.blocks
    assert beside.blocks <= room.blocks + 2  # the frusta's reach past the walls
    assert_same_triangles(beside.mesh, room.mesh)


def test_blocks_share_one_layer_and_cover_the_grid() -> None:
    blocks = fusion_blocks((35, 18, 9), 16)
    assert [tuple(b.start) for b in blocks] == [(0, 0, 0), (0, 16, 0), (16, 0, 0), (16, 16, 0), (32, 0, 0), (32, 16, 0)]
    assert [b.dims for b in blocks] == [(17, 17, 9), (17, 2, 9), (17, 17, 9), (17, 2, 9), (3, 17, 9), (3, 2, 9)]
    # A grid that fits one block exactly is one block (the last layer belongs to no next block).
    assert [b.dims for b in fusion_blocks((17, 17, 9), 16)] == [(17, 17, 9)]
