"""Bounds from evidence: the room's extent comes from its sparse points (and, for stereo, its depth
maps), not from how far the camera frusta reach. An ordinary room (the bundled demo room, whose
tilted frusta span more than 6 m in z) is cut to its points; a space whose points or depths really
span 40 m is kept whole (fused block by block), and only frusta with no evidence are clipped."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.capture.model import Capture, Frame
from engine.geometry.cameras import look_along
from engine.mesh_io import read_ply
from engine.recon import ReconSettings
from engine.recon.plan import plan_reconstruction
from engine.recon.scene_bounds import FRUSTA, SPARSE_POINTS, scene_bounds
from engine.recon.stereo_fusion import fusion_grid
from engine.stereo.depth_maps import DepthMap

DEMO = Path(__file__).resolve().parents[3] / "samples" / "demo_room"
SIZE = (320, 240)
K = np.array([[250.0, 0, 160], [0, 250.0, 120], [0, 0, 1]])


def _capture(poses: list[np.ndarray], points: np.ndarray | None, K: np.ndarray = K) -> Capture:
    frames = [Frame(Path(f"{i:03d}.jpg"), SIZE[0], SIZE[1], K, pose) for i, pose in enumerate(poses)]
    capture = Capture(Path("room"), "synthetic", frames, metric=True)
    return capture.with_points(points) if points is not None else capture


def _surface_points(lo, hi, count: int, seed: int = 0) -> np.ndarray:
    """Points spread over the six faces of the box [lo, hi] (what SfM triangulates on walls, floor, ceiling)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    points = lo + rng.random((count, 3)) * (hi - lo)
    axis, side = rng.integers(0, 3, count), rng.integers(0, 2, count)
    points[np.arange(count), axis] = np.where(side == 1, hi[axis], lo[axis])
    return points


def _room_walk(centre, count: int = 16) -> list[np.ndarray]:
    """Cameras at 1.5 m on a small circle looking outwards, now up at the ceiling, now down at the
    floor, as a hand-held walk does."""
    out = []
    for i in range(count):
        a = 2 * np.pi * i / count
        eye = np.array([centre[0] + 0.4 * np.cos(a), centre[1] + 0.4 * np.sin(a), 1.5])
        out.append(look_along(eye, [np.cos(a), np.sin(a), 0.45 if i % 2 else -0.6]))
    return out


def _plan(capture: Capture, **settings):
    """The plan at a coarse voxel size (few tiles: fast view selection); the bounds do not depend on it."""
    return plan_reconstruction(capture, ReconSettings(voxel_size=0.16, **settings))


def test_a_room_whose_frusta_reach_below_the_floor_is_cut_to_its_points() -> None:
    room = np.array([4.0, 5.0, 3.0])
    poses = _room_walk(room / 2)
    frusta = scene_bounds(K[None].repeat(len(poses), 0), np.stack(poses), np.array([SIZE] * len(poses)))
    assert frusta.clipped[2]  # the frusta alone span more than a 6 m high room
    points = _surface_points([0, 0, 0], room, 3000)
    plan = _plan(_capture(poses, points))
    assert plan.bounds.source == SPARSE_POINTS and not any(plan.bounds.clipped) and not any(plan.bounds.evidence_exceeds)
    # z: the points' extent (floor to ceiling) and a margin, not the frusta's 6 m window.
    assert -0.6 < plan.bounds.minimum[2] <= 0.0 and 3.0 <= plan.bounds.maximum[2] < 3.6
    # Without sparse points nothing says the room is larger than allowed: clipped, silently.
    silent = _plan(_capture(poses, None))
    assert silent.warnings == [] and silent.bounds.source == FRUSTA and silent.bounds.clipped[2]
    assert silent.bounds.size[2] <= 6.0 + 1e-9


def test_the_demo_room_with_points_on_its_surfaces_is_within_the_room_size() -> None:
    K_demo = np.loadtxt(DEMO / "truth" / "intrinsic" / "intrinsic_color.txt")[:3, :3]
    poses = [np.loadtxt(p) for p in sorted((DEMO / "truth" / "pose").glob("*.txt"))]
    truth = read_ply(DEMO / "truth" / "mesh_gt.ply")
    # Sparse points stand-in: a few thousand of the true surface's vertices (SfM finds ~2700).
    points = truth.vertices[np.random.default_rng(0).choice(len(truth.vertices), 2700)]
    plan = _plan(_capture(poses, points, K_demo))
    assert not any(plan.bounds.evidence_exceeds)
    assert np.all(plan.bounds.size <= np.array(ReconSettings().max_room_size))


def test_points_that_really_span_40_m_are_kept_whole() -> None:
    # A 40 m hall walked end to end: cameras every 2 m along x, looking at both side walls.
    poses = [look_along(np.array([x, 2.0 + 0.3 * (i % 2), 1.5]), [0.3, 1.0 if i % 2 else -1.0, -0.1])
             for i, x in enumerate(np.arange(0.0, 40.0, 2.0))]
    points = _surface_points([-0.5, 0, 0], [40.5, 4.0, 3.0], 4000)
    plan = _plan(_capture(poses, points))
    assert plan.bounds.evidence_exceeds == (True, False, False) and not any(plan.bounds.clipped)
    assert plan.warnings == []
    assert plan.bounds.minimum[0] < 0.0 and plan.bounds.maximum[0] > 40.0


def _depth_map(pose: np.ndarray, depth: float) -> DepthMap:
    d = np.full((SIZE[1] // 4, SIZE[0] // 4), depth, np.float32)
    K_small = K.copy()
    K_small[:2] /= 4
    return DepthMap(0, d, np.ones_like(d), K_small, pose, np.zeros(0, np.int64), (0.5, 5.0))


def test_without_sparse_points_the_fusion_grid_is_the_clipped_bounds_cut_to_the_depths() -> None:
    """Without sparse points only the frusta say how large the space is, so they are clipped to the
    maximum room size, and the fusion grid is those bounds cut to where the depth maps saw surfaces:
    the space the learned method's network meshes too (its tiles cover the bounds)."""
    voxel = 0.16
    room_poses = _room_walk([2.0, 2.5])
    plan = _plan(_capture(room_poses, None))
    origin, dims = fusion_grid(plan, [_depth_map(p, 2.0) for p in room_poses], voxel)
    # Depths 2 m out from a 0.4 m ring, image corners included (about 7.4 m) and the fusion margin (5 m).
    assert np.all(np.array(dims[:2]) * voxel < 13.0)
    hall = [look_along(np.array([x, 0.0, 1.5]), [0.0, 1.0, 0.0]) for x in np.arange(0.0, 41.0, 2.0)]
    hall_plan = _plan(_capture(hall, None))
    assert hall_plan.bounds.clipped[0] and hall_plan.bounds.size[0] <= 20.0 + 1e-9
    origin, dims = fusion_grid(hall_plan, [_depth_map(p, 3.0) for p in hall], voxel)
    assert origin[0] >= hall_plan.bounds.minimum[0] - voxel
    assert origin[0] + (dims[0] - 1) * voxel <= hall_plan.bounds.maximum[0] + voxel
