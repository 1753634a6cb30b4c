"""Furniture planes (engine/finish/furniture.py) on the synthetic box room: the cabinet's top and front
found where the room's geometry puts them, a crumpled cabinet top flattened and its hole closed, a
curved surface left alone, and shelves the depth maps see behind a bookcase's front kept. Every
expectation comes from the room's own known geometry."""

from __future__ import annotations

import numpy as np
import pytest

from engine.finish.finishing import FinishOptions, finish_mesh
from engine.finish.free_space import PlainDepthView, surface_offsets
from engine.finish.furniture import FRONT, TOP, find_furniture_planes, furniture_grid
from engine.finish.modes import FINISH_ROOM
from engine.finish.planes import face_geometry, find_structural_planes
from engine.geometry.depth_render import render_depth
from engine.mesh_io import Mesh
from engine.observation import ADDED
from fixtures_box_room import CABINET, box_parts, cameras, merge, rectangle, room_parts, truth_with_next_room

X0, X1, Y0, Y1, Z0, Z1 = CABINET  # the cabinet against the x = 0 wall: its top at z = Z1, its front at x = X1
HOLE_IN_TOP = (0.3, 0.5, 1.4, 1.6)  # x0, x1, y0, y1: missing from the reconstructed top (a highlight)


def _views(parts):
    K, poses = cameras()
    vertices, faces = merge(parts)
    return [PlainDepthView(render_depth(vertices, faces, K, pose, (96, 72)), K, pose) for pose in poses], poses


def _room_without_cabinet():
    return [p for p in room_parts(with_hole=False)][:6]


def _crumpled(parts, rng, sigma):
    """The parts' vertices moved along z (tops) or their normal's axis by Gaussian noise of `sigma` m."""
    vertices, faces = merge(parts)
    return vertices + rng.normal(0.0, sigma, vertices.shape), faces


def _planes(vertices, faces, poses):
    planes, info = find_structural_planes(vertices, faces, poses[:, :3, 3])
    centroids, areas, normals = face_geometry(vertices, faces)
    return planes, info, centroids, areas, normals


def test_the_cabinets_top_and_front_are_found_where_they_stand():
    rng = np.random.default_rng(0)
    # The cabinet as the photos see it: without the side against the wall (box_parts' fourth, at x = X0).
    cabinet = [part for k, part in enumerate(box_parts(*CABINET)) if k != 3]
    vertices, faces = _crumpled(_room_without_cabinet() + cabinet, rng, 0.01)
    _, poses = cameras()
    planes, info, centroids, areas, normals = _planes(vertices, faces, poses)
    found = find_furniture_planes(centroids, areas, normals, np.array([0.0, 0.0, 1.0]), info["heading_deg"], planes)
    tops = [f.plane for f in found if f.plane.kind == TOP]
    fronts = [f.plane for f in found if f.plane.kind == FRONT]
    assert len(tops) == 1 and abs(tops[0].offset - Z1) < 0.01 and tops[0].normal[2] > 0.999
    assert abs(tops[0].area - (X1 - X0) * (Y1 - Y0)) < 0.1 * (X1 - X0) * (Y1 - Y0)
    # The front faces +x at x = X1 (offset = n . x); the cabinet's ends (0.8 x 0.9 m) face -y and +y.
    front = next(p for p in fronts if p.normal[0] > 0.99)
    assert abs(front.offset - X1) < 0.01
    # Where each end stands along y (offset = n . x, so y = offset / n_y).
    ends = sorted(p.offset / round(float(p.normal[1])) for p in fronts if abs(p.normal[1]) > 0.99)
    assert ends == pytest.approx([Y0, Y1], abs=0.01)
    # Nothing of the room's own planes is taken for furniture.
    assert len(found) == 4


def test_a_crumpled_cabinet_top_is_flattened_and_its_hole_closed():
    """3 cm of noise on the cabinet (1 cm on the room) and a hole in its top that every view saw the
    top through: Finish Room lays the top flat at its height, with the hole closed and marked added."""
    rng = np.random.default_rng(1)
    in_hole = lambda s, t: HOLE_IN_TOP[0] <= s + X0 < HOLE_IN_TOP[1] and HOLE_IN_TOP[2] <= t + Y0 < HOLE_IN_TOP[3]
    cabinet = box_parts(*CABINET)
    cabinet[0] = rectangle((X0, Y0, Z1), (1, 0, 0), (0, 1, 0), X1 - X0, Y1 - Y0, (0, 0, 1), skip=in_hole)
    room_v, room_f = _crumpled(_room_without_cabinet(), rng, 0.01)
    cab_v, cab_f = _crumpled(cabinet, rng, 0.03)
    vertices, faces = merge([(room_v, room_f), (cab_v, cab_f)])
    views, poses = _views(room_parts(with_hole=False))
    mesh = Mesh(vertices.astype(np.float32), faces.astype(np.int32))

    result = finish_mesh(mesh, views, poses[:, :3, 3], 0.04, FINISH_ROOM)
    assert any(f["kind"] == TOP for f in result.stats["furniture"])
    out_v, out_f = np.asarray(result.mesh.vertices, np.float64), np.asarray(result.mesh.faces)
    centroids, areas, _ = face_geometry(out_v, out_f)
    over_top = ((centroids[:, 0] > X0 + 0.1) & (centroids[:, 0] < X1 - 0.1) & (centroids[:, 1] > Y0 + 0.1)
                & (centroids[:, 1] < Y1 - 0.1) & (np.abs(centroids[:, 2] - Z1) < 0.2))
    # Flat: the top's surface lies within 1 cm of z = Z1 (its noise was 3 cm).
    assert np.abs(centroids[over_top, 2] - Z1).max() < 0.01
    # Closed: the hole's cells are covered, by faces marked added.
    in_hole_faces = over_top & (centroids[:, 0] > HOLE_IN_TOP[0]) & (centroids[:, 0] < HOLE_IN_TOP[1]) & \
        (centroids[:, 1] > HOLE_IN_TOP[2]) & (centroids[:, 1] < HOLE_IN_TOP[3])
    hole_area = (HOLE_IN_TOP[1] - HOLE_IN_TOP[0]) * (HOLE_IN_TOP[3] - HOLE_IN_TOP[2])
    assert areas[in_hole_faces].sum() > 0.9 * hole_area
    well_inside = over_top & (centroids[:, 0] > HOLE_IN_TOP[0] + 0.05) & (centroids[:, 0] < HOLE_IN_TOP[1] - 0.05) & \
        (centroids[:, 1] > HOLE_IN_TOP[2] + 0.05) & (centroids[:, 1] < HOLE_IN_TOP[3] - 0.05)
    added = np.asarray(result.mesh.attributes[ADDED])[out_f[well_inside]]
    assert (added == 1).all()
    # Without furniture planes the crumple stays (the comparison that shows the step did it).
    plain = finish_mesh(mesh, views, poses[:, :3, 3], 0.04, FINISH_ROOM, FinishOptions(furniture=False))
    c2, _, _ = face_geometry(np.asarray(plain.mesh.vertices, np.float64), np.asarray(plain.mesh.faces))
    over_top2 = ((c2[:, 0] > X0 + 0.1) & (c2[:, 0] < X1 - 0.1) & (c2[:, 1] > Y0 + 0.1) & (c2[:, 1] < Y1 - 0.1)
                 & (np.abs(c2[:, 2] - Z1) < 0.2))
    assert np.abs(c2[over_top2, 2] - Z1).max() > 0.03


def test_a_curved_surface_is_no_furniture_plane():
    """A half cylinder of 0.4 m radius standing in the room (a sofa's back, a curved screen) is turned
    every way within 45 deg of its axis of symmetry: its surface spreads over 6 cm about any plane."""
    rng = np.random.default_rng(2)
    room_v, room_f = _crumpled(_room_without_cabinet(), rng, 0.01)
    angles = np.linspace(-np.pi / 2, np.pi / 2, 41)
    heights = np.linspace(0.0, 1.0, 26)
    a, h = np.meshgrid(angles, heights, indexing="ij")
    centre = np.array([2.0, 1.5])
    cyl_v = np.stack([centre[0] + 0.4 * np.cos(a.ravel()), centre[1] + 0.4 * np.sin(a.ravel()), h.ravel()], axis=1)
    quads = [(i * 26 + j, (i + 1) * 26 + j, (i + 1) * 26 + j + 1, i * 26 + j + 1) for i in range(40) for j in range(25)]
    cyl_f = np.array([(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads])
    vertices, faces = merge([(room_v, room_f), (cyl_v, cyl_f)])
    _, poses = cameras()
    planes, info, centroids, areas, normals = _planes(vertices, faces, poses)
    on_cylinder = np.abs(np.linalg.norm(centroids[:, :2] - centre, axis=1) - 0.4) < 0.02
    found = find_furniture_planes(centroids, areas, normals, np.array([0.0, 0.0, 1.0]), info["heading_deg"], planes)
    for patch in found:
        assert on_cylinder[patch.faces].mean() < 0.5


def test_shelves_the_depth_maps_see_behind_a_bookcase_front_stay():
    """A bookcase 1 m wide against the x = 0 wall: its front frame (5 cm bars) at x = 0.4 and two
    shelves' books 6 cm behind it, in the reconstruction and in the views' depth. The front is a furniture
    plane; the books stay where they are (relief), and the frame lies on the plane."""
    frame_x, depth = 0.4, 0.06
    y0, y1, z0, z1 = 1.0, 2.0, 0.0, 1.0
    inside = lambda s, t: 0.05 <= s < 0.95 and (0.05 <= t < 0.475 or 0.525 <= t < 0.95)
    front = rectangle((frame_x, y0, z0), (0, 1, 0), (0, 0, 1), y1 - y0, z1 - z0, (1, 0, 0), step=0.025, skip=inside)
    books = rectangle((frame_x - depth, y0, z0), (0, 1, 0), (0, 0, 1), y1 - y0, z1 - z0, (1, 0, 0), step=0.025,
                      skip=lambda s, t: not inside(s, t))
    parts = _room_without_cabinet() + [front, books]
    views, poses = _views(parts)
    rng = np.random.default_rng(3)
    vertices, faces = _crumpled(parts, rng, 0.005)
    planes, info, centroids, areas, normals = _planes(vertices, faces, poses)
    found = [f for f in find_furniture_planes(centroids, areas, normals, np.array([0.0, 0.0, 1.0]), info["heading_deg"],
                                              planes) if f.plane.kind == FRONT and f.plane.normal[0] > 0.99]
    assert len(found) == 1
    # The plane is the bigger layer's (the books'); the frame, which the maps see 6 cm in front of it, is
    # relief.
    grid = furniture_grid(found[0], centroids, 0.025, views, fill=True)
    assert found[0].plane.offset == pytest.approx(frame_x - depth, abs=0.01)
    frame_points = np.array([[frame_x, y, 0.5] for y in np.linspace(1.1, 1.9, 9)] +
                            [[frame_x, y, z] for y in (1.02, 1.98) for z in np.linspace(0.1, 0.9, 9)])
    assert grid.in_relief(frame_points).mean() > 0.75  # the bars' outer edges are the grid's border cells
    # Finished, both stay where they are: the books 6 cm behind the frame.
    mesh = Mesh(vertices.astype(np.float32), faces.astype(np.int32))
    result = finish_mesh(mesh, views, poses[:, :3, 3], 0.04, FINISH_ROOM)
    out_c, _, out_n = face_geometry(np.asarray(result.mesh.vertices, np.float64), np.asarray(result.mesh.faces))
    facing = (out_n[:, 0] > 0.9) & (out_c[:, 0] > 0.2)  # the bookcase, not the wall behind it
    shelf = facing & (out_c[:, 1] > 1.1) & (out_c[:, 1] < 1.9) & (out_c[:, 2] > 0.1) & (out_c[:, 2] < 0.4)
    middle_bar = facing & (out_c[:, 1] > 1.1) & (out_c[:, 1] < 1.9) & (np.abs(out_c[:, 2] - 0.5) < 0.015)
    assert np.median(out_c[shelf, 0]) == pytest.approx(frame_x - depth, abs=0.01)
    assert middle_bar.sum() > 10 and np.median(out_c[middle_bar, 0]) == pytest.approx(frame_x, abs=0.01)


def test_surface_offsets_are_where_the_maps_put_the_surface():
    """A camera 2 m over the plane z = 0 whose map sees a floor 5 cm below it: -0.05 everywhere it frames,
    NaN where fewer than two views say, and outside `reach`."""
    K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
    pose[:3, 3] = [0.0, 0.0, 2.0]
    view = PlainDepthView(np.full((48, 64), 2.05, np.float32), K, pose)
    points = np.c_[np.random.default_rng(0).uniform(-0.5, 0.5, (50, 2)), np.zeros(50)]
    normal = np.array([0.0, 0.0, 1.0])
    assert surface_offsets(points, normal, 0.0, [view, view], 0.2) == pytest.approx(np.full(50, -0.05), abs=1e-5)
    assert np.isnan(surface_offsets(points, normal, 0.0, [view], 0.2)).all()
    assert np.isnan(surface_offsets(points, normal, 0.0, [view, view], 0.04)).all()


def test_a_wall_sized_panel_is_no_furniture_plane():
    """A free-standing 3.5 x 2 m panel (7 m^2: a wall the structural planes did not take) is left to
    them: laid on one plane it would lose the drift a wall's own grid follows. A 1 x 1 m one is taken."""
    rng = np.random.default_rng(4)
    room_v, room_f = _crumpled(_room_without_cabinet(), rng, 0.01)
    big = rectangle((0.25, 1.0, 0.0), (1, 0, 0), (0, 0, 1), 3.5, 2.0, (0, 1, 0))
    small = rectangle((1.5, 2.2, 0.0), (1, 0, 0), (0, 0, 1), 1.0, 1.0, (0, -1, 0))
    vertices, faces = merge([(room_v, room_f), big, small])
    _, poses = cameras()
    planes, info, centroids, areas, normals = _planes(vertices, faces, poses)
    found = find_furniture_planes(centroids, areas, normals, np.array([0.0, 0.0, 1.0]), info["heading_deg"], planes)
    assert not any(f.plane.normal[1] > 0.99 and abs(f.plane.offset - 1.0) < 0.05 for f in found)
    assert any(f.plane.normal[1] < -0.99 and abs(f.plane.offset + 2.2) < 0.05 for f in found)
