"""Which candidates are walls: what a wall's windows show of outside does not count against it, what
is seen over a partition does."""

from __future__ import annotations

import numpy as np

from engine.finish.planes import FLOOR, WALL, face_geometry, find_structural_planes, seen_through_openings
from fixtures_box_room import ROOM, cameras, merge, rectangle, room_parts

WINDOWS = ((0.3, 1.3), (1.7, 2.7))  # along y in the x = 4 wall
SILL, LINTEL = 0.8, 2.0  # window heights


def _in_window(s: float, t: float) -> bool:
    return SILL <= t < LINTEL and any(a <= s < b for a, b in WINDOWS)


def _room_with_windows_and_backdrop():
    """The box room with its x = 4 wall holding two 1 x 1.2 m windows, and outside them a backdrop 2 m
    behind the wall (a facade across the street), larger than the wall itself."""
    X, Y, Z = ROOM
    parts = [p for p in room_parts(with_hole=False)]
    parts[5] = rectangle((X, 0, 0), (0, 1, 0), (0, 0, 1), Y, Z, (-1, 0, 0), skip=_in_window)
    parts.append(rectangle((X + 2.0, -3.0, 0.0), (0, 1, 0), (0, 0, 1), 9.0, Z, (-1, 0, 0), step=0.05))
    return merge(parts)


def test_a_wall_with_windows_is_found_behind_what_they_show():
    vertices, faces = _room_with_windows_and_backdrop()
    _, poses = cameras()
    planes, _ = find_structural_planes(vertices, faces, poses[:, :3, 3])
    walls = [p for p in planes if p.kind == WALL and p.normal[0] < -0.99]
    offsets = sorted(round(-p.offset, 2) for p in walls)
    assert ROOM[0] in offsets, f"the window wall at x = 4 must be found, got walls at x = {offsets}"


def test_what_the_windows_show_is_seen_through_them_and_the_wall_itself_hides_the_rest():
    X, Y, Z = ROOM
    _, poses = cameras()
    direction = np.array([-1.0, 0.0, 0.0])  # the wall's normal, into the room
    u_axis = np.cross([0.0, 0.0, 1.0], direction)
    wall, _, _ = face_geometry(*rectangle((X, 0, 0), (0, 1, 0), (0, 0, 1), Y, Z, (-1, 0, 0), skip=_in_window))
    wall_uz = np.stack([wall @ u_axis, wall[:, 2]], axis=1)  # the wall's own faces: along it, height
    # Behind the wall, 2 m out: straight out through the middle of a window, and straight out from the
    # wall's middle between the windows (no camera's sight line reaches it through an opening).
    behind = np.array([[X + 2.0, 0.8, 1.4], [X + 2.0, 1.5, 1.4]])
    through = seen_through_openings(wall_uz, behind, poses[:, :3, 3], direction, -X, u_axis)
    assert through.tolist() == [True, False]


def test_a_partition_with_the_room_seen_over_it_is_not_a_wall():
    """A 1.5 m partition across the room at x = 3: the far wall shows over it, where the partition has
    no surface above the sight lines, so it counts against the partition."""
    X, Y, Z = ROOM
    parts = room_parts(with_hole=False) + [rectangle((3.0, 0, 0), (0, 1, 0), (0, 0, 1), Y, 1.5, (-1, 0, 0))]
    vertices, faces = merge(parts)
    _, poses = cameras()
    planes, _ = find_structural_planes(vertices, faces, poses[:, :3, 3])
    offsets = sorted(round(-p.offset, 2) for p in planes if p.kind == WALL and p.normal[0] < -0.99)
    assert offsets == [X], f"only the far wall is a wall, got walls at x = {offsets}"


def test_a_wall_whose_door_lintel_stereo_missed_is_found_behind_what_the_door_shows():
    """The x = 4 wall reconstructed only up to 1.9 m (plain wall above a door is often not found), with a
    1 m door from the floor up: through it the next room shows (a patch larger than the wall itself).
    With no surface above the door, the gap is an opening because the wall stands on both sides of it."""
    X, Y, Z = ROOM
    height = 1.9
    in_door = lambda s, t: 1.0 <= s < 2.0  # noqa: E731
    parts = [p for p in room_parts(with_hole=False)]
    parts[5] = rectangle((X, 0, 0), (0, 1, 0), (0, 0, 1), Y, height, (-1, 0, 0), skip=in_door)
    parts.append(rectangle((X + 2.0, 0.5, 0.0), (0, 1, 0), (0, 0, 1), 2.0, 2.2, (-1, 0, 0), step=0.05))
    vertices, faces = merge(parts)
    _, poses = cameras()
    planes, _ = find_structural_planes(vertices, faces, poses[:, :3, 3])
    offsets = sorted(round(-p.offset, 2) for p in planes if p.kind == WALL and p.normal[0] < -0.99)
    assert X in offsets, f"the wall with the door at x = 4 must be found, got walls at x = {offsets}"


def _corridor_cameras(length: float) -> np.ndarray:
    return np.array([[x, 0.8, 1.5] for x in np.arange(0.5, length, 0.5)])


def test_a_glossy_floors_reflection_below_it_is_not_the_floor():
    # A 12 x 1.6 m corridor floor at z = 0 whose far end stereo did not match, and 1.4 m^2 of the
    # mirrored lights matched 26 cm below it there (the 3D Scanner App corridor's glossy floor).
    missing = lambda s, t: 9.0 <= s < 10.2  # noqa: E731
    vertices, faces = merge([
        rectangle((0, 0, 0), (1, 0, 0), (0, 1, 0), 12.0, 1.6, (0, 0, 1), skip=missing),
        rectangle((9.0, 0.2, -0.26), (1, 0, 0), (0, 1, 0), 1.2, 1.2, (0, 0, 1)),
        rectangle((0, 0, 0), (1, 0, 0), (0, 0, 1), 12.0, 2.5, (0, 1, 0)),
        rectangle((0, 1.6, 0), (1, 0, 0), (0, 0, 1), 12.0, 2.5, (0, -1, 0)),
    ])
    planes, _ = find_structural_planes(vertices, faces, _corridor_cameras(12.0))
    floor = next(p for p in planes if p.kind == FLOOR)
    assert abs(floor.offset) < 0.03


def test_a_table_over_a_floor_barely_seen_is_not_the_floor():
    # The kitchen of issue 43: the table top (1.5 m^2 at 0.75 m) fills the photos, the floor shows in
    # 0.5 m^2 beside it; both have little below them, but the table is furniture-sized.
    vertices, faces = merge([
        rectangle((0, 0, 0.75), (1, 0, 0), (0, 1, 0), 1.5, 1.0, (0, 0, 1)),
        rectangle((1.8, 0, 0), (1, 0, 0), (0, 1, 0), 0.5, 1.0, (0, 0, 1)),
    ])
    planes, _ = find_structural_planes(vertices, faces, np.array([[0.7, -1.0, 1.6], [1.5, -1.2, 1.5]]))
    floor = next(p for p in planes if p.kind == FLOOR)
    assert abs(floor.offset) < 0.03


def test_a_glass_front_seen_from_its_back_is_the_wall_of_the_leg_beside_it_facing_that_leg():
    """Two parallel 2 m corridors 3 m apart (photos along y = 1 and y = 6) with nothing between them but
    a framed glass front at y = 2.2 whose stereo surface faces the far corridor (its frames and
    transoms, as the 3D Scanner App corridor's office fronts came out): seen through its openings from
    the far leg, it passes as a wall facing +y, and its back would cut the near leg's floor. The
    photos nearest it stood behind it: it is the near leg's wall, seen through, and faces them."""
    from fixtures_box_room import merge, rectangle

    Z = 2.5
    glass_pane = lambda s, t: (s % 1.0) > 0.15 and t < 2.0  # 15 cm mullions every metre, a transom above 2 m
    parts = [
        rectangle((0, 0, 0), (1, 0, 0), (0, 1, 0), 8.0, 2.0, (0, 0, 1)),  # near leg's floor (no ceiling: stereo's is sparse)
        rectangle((0, 0, 0), (1, 0, 0), (0, 0, 1), 8.0, Z, (0, 1, 0)),  # its outer wall, y = 0
        rectangle((0, 5, 0), (1, 0, 0), (0, 1, 0), 8.0, 2.0, (0, 0, 1)),  # far leg's floor
        rectangle((0, 5, Z), (1, 0, 0), (0, 1, 0), 8.0, 2.0, (0, 0, -1)),
        rectangle((0, 7, 0), (1, 0, 0), (0, 0, 1), 8.0, Z, (0, -1, 0)),  # its outer wall, y = 7
        rectangle((0, 2.2, 0), (1, 0, 0), (0, 0, 1), 8.0, Z, (0, 1, 0), skip=glass_pane),  # the glass front's back
    ]
    vertices, faces = merge(parts)
    cameras = np.array([(x, y, 1.5) for y in (1.0, 6.0) for x in np.arange(0.5, 8.0, 0.5)])
    planes, _ = find_structural_planes(vertices, faces, cameras)
    walls = [(tuple(np.round(p.normal, 3)), round(p.offset, 2)) for p in planes if p.kind == WALL]
    assert ((0.0, 1.0, 0.0), 0.0) in walls and ((0.0, -1.0, 0.0), -7.0) in walls  # both outer walls
    assert not any(normal[1] > 0.99 and abs(offset - 2.2) < 0.1 for normal, offset in walls), walls
    assert any(normal[1] < -0.99 and abs(offset + 2.2) < 0.1 for normal, offset in walls), walls


def test_a_walk_through_a_door_frame_crosses_it_at_an_opening_one_along_a_glass_front_does_not():
    """The door frame across a corridor (jambs to y = 0.5 and from 1.5, a lintel above 2.1 m, on x = 5):
    the walk down the corridor's middle crosses its plane 0.5 m from any of it. A glass front along the
    walk (y = 2, x 0..6, framed to its end) is crossed only at the corner, where the walk turns round its
    end: within its own surface's reach."""
    from engine.finish.planes import _walked_through_an_opening

    def grid(u0, u1, z0, z1, step=0.05):
        u, z = np.meshgrid(np.arange(u0, u1 + 1e-9, step), np.arange(z0, z1 + 1e-9, step), indexing="ij")
        return np.stack([u.ravel(), z.ravel()], axis=1)

    # The frame faces +x: u = z x (+x) = +y.
    frame = np.concatenate([grid(0.0, 0.5, 0.0, 2.5), grid(1.5, 2.0, 0.0, 2.5), grid(0.5, 1.5, 2.1, 2.5)])
    walk = np.array([(x, 1.0, 1.5) for x in np.arange(0.5, 10.0, 0.5)])
    assert _walked_through_an_opening(frame, walk, np.array([1.0, 0, 0]), 5.0, np.array([0, 1.0, 0]))

    # The glass front faces -y (into the offices beyond y = 2): u = z x (-y) = +x. The walk goes along
    # y = 1 to x = 6.2, then turns into a leg beyond the front's end (y from 2 to 5).
    glass = grid(0.0, 6.0, 0.0, 2.5)
    walk = np.array([(x, 1.0, 1.5) for x in np.arange(0.5, 6.3, 0.5)] + [(6.2, y, 1.5) for y in np.arange(1.5, 5.0, 0.5)])
    assert not _walked_through_an_opening(glass, walk, np.array([0, -1.0, 0]), -2.0, np.array([1.0, 0, 0]))
