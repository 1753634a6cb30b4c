"""What other views confirm of a depth map: a fattened edge and a patch of chance matches take back the
surface their neighbours and the other views agree on; nothing is dropped; the order of the maps does
not matter. The scene is exact (ray cast): a panel 2 m away in front of a wall 3 m away, five cameras
side by side looking at it."""

from __future__ import annotations

import numpy as np

from engine.stereo.depth_maps import DepthMap
from engine.stereo.view_agreement import adopt_confirmed_planes, candidate_offsets, confirmations_at, neighbour_planes

WIDTH, HEIGHT, FOCAL = 100, 80, 80.0
K = np.array([[FOCAL, 0.0, WIDTH / 2], [0.0, FOCAL, HEIGHT / 2], [0.0, 0.0, 1.0]])
PANEL_Z, WALL_Z, PANEL_HALF = 2.0, 3.0, 0.3  # metres; the panel spans x, y in [-0.3, 0.3]
FACING = np.array([0.0, 0.0, -1.0], np.float32)  # both surfaces face the cameras (camera axes = world axes)


def scene_map(frame: int, x: float) -> DepthMap:
    """The exact depth and normals seen by a camera at (x, 0, 0) looking along +z."""
    pose = np.eye(4)
    pose[0, 3] = x
    cols, rows = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    ray_x, ray_y = (cols - K[0, 2]) / FOCAL, (rows - K[1, 2]) / FOCAL
    on_panel = (np.abs(x + PANEL_Z * ray_x) <= PANEL_HALF) & (np.abs(PANEL_Z * ray_y) <= PANEL_HALF)
    depth = np.where(on_panel, PANEL_Z, WALL_Z).astype(np.float32)
    normal = np.broadcast_to(FACING, (HEIGHT, WIDTH, 3)).copy()
    return DepthMap(frame, depth, np.ones_like(depth), K.copy(), pose, np.zeros(0, np.int64), (0.5, 6.0), normal=normal)


def scene_maps() -> list[DepthMap]:
    return [scene_map(i, x) for i, x in enumerate((-0.2, -0.1, 0.0, 0.1, 0.2))]


def panel_right_edge(m: DepthMap) -> int:
    """The first column right of the panel in the map's middle row."""
    row = m.depth[HEIGHT // 2]
    return int(np.flatnonzero(row == PANEL_Z).max()) + 1


def test_a_fattened_edge_and_chance_matches_take_the_plane_the_other_views_confirm():
    maps = scene_maps()
    exact = [m.depth.copy() for m in maps]
    centre = maps[2]
    edge = panel_right_edge(centre)
    rows = slice(HEIGHT // 2 - 10, HEIGHT // 2 + 10)
    # The window carried the panel 3 px over its right edge onto the wall, and a patch of the wall
    # settled 6 % too near (a chance match on fine texture), with a tilted normal.
    centre.depth[rows, edge:edge + 3] = PANEL_Z
    centre.depth[10:14, 10:14] *= 0.94
    centre.normal[10:14, 10:14] = np.array([0.3, 0.0, -0.954], np.float32)

    changed = adopt_confirmed_planes(maps)

    assert np.allclose(centre.depth[rows, edge:edge + 3], WALL_Z, rtol=1e-5), "the band is wall again"
    assert np.allclose(centre.depth[10:14, 10:14], WALL_Z, rtol=1e-5)
    assert np.allclose(centre.normal[10:14, 10:14], FACING), "the plane's normal comes with its depth"
    assert changed[2] == 20 * 3 + 16
    for m, before in zip(maps, exact):  # everything else, in every map, is as it was
        if m is not centre:
            assert np.array_equal(m.depth, before)
    assert np.array_equal(centre.depth, exact[2])


def test_a_depth_no_other_view_confirms_and_no_neighbour_can_replace_stays():
    """The other view sees nothing here: the geometric filter would drop the whole map; this keeps it."""
    lone = scene_map(0, 0.0)
    blind = scene_map(1, 0.1)
    blind.depth[:] = 0.0
    before = lone.depth.copy()
    assert adopt_confirmed_planes([lone, blind]) == [0, 0]
    assert np.array_equal(lone.depth, before)


def test_the_result_does_not_depend_on_the_order_of_the_maps():
    def corrupted() -> list[DepthMap]:
        maps = scene_maps()
        for k, m in enumerate(maps):  # each map fattened on its own side, as each view's window is
            edge = panel_right_edge(m)
            m.depth[20 + 5 * k:40 + 5 * k, edge:edge + 2] = PANEL_Z
        return maps

    forward, backward = corrupted(), corrupted()[::-1]
    adopt_confirmed_planes(forward)
    adopt_confirmed_planes(backward)
    for a, b in zip(forward, backward[::-1]):
        assert np.array_equal(a.depth, b.depth)


def test_confirmations_follow_the_point_and_its_normal():
    maps = scene_maps()
    v, u = np.array([HEIGHT // 2, 5]), np.array([WIDTH // 2, 5])  # a panel pixel and a wall pixel of the centre view
    right = maps[2].depth[v, u]
    assert confirmations_at(maps, 2, v, u, right, maps[2].normal[v, u]).min() >= 3
    assert confirmations_at(maps, 2, v, u, right * 1.05, maps[2].normal[v, u]).max() == 0  # 5 % off
    tilted = np.tile(np.array([0.6, 0.0, -0.8]), (2, 1))  # 37 deg off: beyond the 25 deg agreement
    assert confirmations_at(maps, 2, v, u, right, tilted).max() == 0
    # The neighbours tried: 8 directions at each radius, nearest first.
    offsets = candidate_offsets((2, 4))
    assert len(offsets) == 16 and max(abs(d) for o in offsets[:8] for d in o) == 2


def test_each_neighbour_offers_its_own_plane_once():
    """A pixel on the panel's right edge: the neighbours to its right offer the wall (3 m), those to its
    left the panel, which is its own surface and not offered; the wall is offered once, by the nearest."""
    m = scene_map(0, 0.0)
    edge = panel_right_edge(m)
    v, u = np.array([HEIGHT // 2]), np.array([edge - 1])
    offsets = [(0, 2), (0, -2), (0, 4), (2, 2)]
    depths, normals, tried = neighbour_planes(m, v, u, offsets)
    assert depths.shape == (4, 1) and normals.shape == (4, 1, 3) and tried.shape == (4, 1)
    assert np.allclose(depths[:, 0], [WALL_Z, PANEL_Z, WALL_Z, WALL_Z])
    assert tried[:, 0].tolist() == [True, False, False, False]
