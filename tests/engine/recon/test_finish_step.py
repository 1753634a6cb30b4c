"""The finishing stage inside a reconstruction (engine/recon/finish_step.py): off leaves the mesh as
marching cubes made it; room finishes it, with the run's depth maps or, for a method without any (VoRTX
with appearance-only weights), the mesh's own depth from the keyframes."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from engine.mesh_io import Mesh
from engine.observation import ADDED
from engine.recon.finish_step import finish_reconstruction
from engine.recon.settings import ReconSettings
from fixtures_box_room import ROOM, cameras, merge, room_parts


def _plan_and_mesh():
    K, poses = cameras()
    plan = SimpleNamespace(keyframes=list(range(len(poses))), Ks=np.repeat(K[None], len(poses), axis=0), poses=poses,
                           sizes=np.tile([96, 72], (len(poses), 1)))
    vertices, faces = merge(room_parts(with_hole=True))
    noisy = vertices + np.random.default_rng(1).normal(0, 0.01, vertices.shape)
    return plan, Mesh(noisy.astype(np.float32), faces.astype(np.int32))


def test_off_keeps_the_mesh_and_reports_nothing():
    plan, mesh = _plan_and_mesh()
    out, stats = finish_reconstruction(mesh, plan, ReconSettings(finish="off"))
    assert out is mesh and stats is None


def test_room_without_depth_maps_uses_the_meshs_own_depth():
    plan, mesh = _plan_and_mesh()
    out, stats = finish_reconstruction(mesh, plan, ReconSettings(finish="room"))
    kinds = sorted(p["kind"] for p in stats["planes"])
    assert kinds == ["ceiling", "floor", "wall", "wall", "wall", "wall"]
    # The floor is flat where it was noisy (1 cm): its faces lie on z = 0 within a few mm.
    centroids = out.vertices[out.faces].mean(axis=1)
    floor = ((np.abs(centroids[:, 2]) < 0.05) & (centroids[:, 0] > 1.0) & (centroids[:, 0] < ROOM[0] - 0.2)
             & (centroids[:, 1] > 0.2) & (centroids[:, 1] < ROOM[1] - 0.2))  # away from the walls' bottom rows
    assert floor.sum() > 1000 and np.abs(centroids[floor, 2]).max() < 0.003
    assert ADDED in out.attributes and len(out.attributes[ADDED]) == len(out.vertices)
    assert out.normals is not None and len(out.normals) == len(out.vertices)
