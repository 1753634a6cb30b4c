"""A synthetic box room for the finishing tests: a 4 x 3 x 2.5 m room with a door open onto the next
room, a hole in one wall (in the reconstruction only), a cabinet against a wall, and cameras in the
middle looking round; every surface wound toward the room. Built from known rectangles, so tests can
check the finishing against the room's own geometry."""

from __future__ import annotations

import numpy as np

ROOM = np.array([4.0, 3.0, 2.5])  # x, y, z extent of the box room, metres; floor at z = 0
DOOR = (1.2, 2.0, 0.0, 2.0)  # in the y = 3 wall: x from 1.2 to 2.0, z from 0 to 2.0 (open: the next room shows)
HOLE = (1.0, 1.6, 0.8, 1.4)  # in the x = 4 wall: y 1.0..1.6, z 0.8..1.4 missing from the reconstruction only
CABINET = (0.0, 0.8, 1.0, 2.0, 0.0, 0.9)  # x0, x1, y0, y1, z0, z1: furniture against the x = 0 wall
STEP = 0.04


def rectangle(origin, u, v, size_u, size_v, normal, step=STEP, skip=None):
    """(vertices, faces) of a grid rectangle origin + s u + t v, wound so the face normal is `normal`;
    `skip(s, t)` -> True drops the cell whose lower corner is (s, t)."""
    origin, u, v = (np.asarray(a, float) for a in (origin, u, v))
    ns, nt = int(round(size_u / step)), int(round(size_v / step))
    s, t = np.meshgrid(np.arange(ns + 1) * step, np.arange(nt + 1) * step, indexing="ij")
    vertices = origin + s.reshape(-1, 1) * u + t.reshape(-1, 1) * v
    faces = []
    for i in range(ns):
        for j in range(nt):
            if skip is not None and skip(i * step + step / 2, j * step + step / 2):
                continue
            a, b, c, d = i * (nt + 1) + j, (i + 1) * (nt + 1) + j, (i + 1) * (nt + 1) + j + 1, i * (nt + 1) + j + 1
            faces += [(a, b, c), (a, c, d)]
    faces = np.array(faces, np.int64).reshape(-1, 3)
    if len(faces) and np.cross(u, v) @ np.asarray(normal, float) < 0:
        faces = faces[:, ::-1]
    return vertices, faces


def merge(parts):
    vertices, faces, offset = [], [], 0
    for v, f in parts:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def box_parts(x0, x1, y0, y1, z0, z1, outward=True):
    """The five visible sides (no bottom) of an axis box, normals outward."""
    sign = 1 if outward else -1
    return [
        rectangle((x0, y0, z1), (1, 0, 0), (0, 1, 0), x1 - x0, y1 - y0, (0, 0, sign)),
        rectangle((x0, y0, z0), (1, 0, 0), (0, 0, 1), x1 - x0, z1 - z0, (0, -sign, 0)),
        rectangle((x0, y1, z0), (1, 0, 0), (0, 0, 1), x1 - x0, z1 - z0, (0, sign, 0)),
        rectangle((x0, y0, z0), (0, 1, 0), (0, 0, 1), y1 - y0, z1 - z0, (-sign, 0, 0)),
        rectangle((x1, y0, z0), (0, 1, 0), (0, 0, 1), y1 - y0, z1 - z0, (sign, 0, 0)),
    ]


def room_parts(with_hole: bool):
    """The room's surfaces as (vertices, faces) parts, normals into the room. The door is open in both
    the truth and the reconstruction; the hole only in the reconstruction (`with_hole`)."""
    X, Y, Z = ROOM
    in_door = lambda s, t: DOOR[0] <= s < DOOR[1] and DOOR[2] <= t < DOOR[3]
    in_hole = lambda s, t: with_hole and HOLE[0] <= s < HOLE[1] and HOLE[2] <= t < HOLE[3]
    parts = [
        rectangle((0, 0, 0), (1, 0, 0), (0, 1, 0), X, Y, (0, 0, 1)),  # floor
        rectangle((0, 0, Z), (1, 0, 0), (0, 1, 0), X, Y, (0, 0, -1)),  # ceiling
        rectangle((0, 0, 0), (1, 0, 0), (0, 0, 1), X, Z, (0, 1, 0)),  # y = 0 wall
        rectangle((0, Y, 0), (1, 0, 0), (0, 0, 1), X, Z, (0, -1, 0), skip=in_door),  # y = Y wall, with the door
        rectangle((0, 0, 0), (0, 1, 0), (0, 0, 1), Y, Z, (1, 0, 0)),  # x = 0 wall
        rectangle((X, 0, 0), (0, 1, 0), (0, 0, 1), Y, Z, (-1, 0, 0), skip=in_hole),  # x = X wall
    ]
    parts += box_parts(*CABINET)
    return parts


def truth_with_next_room():
    """The true scene for the views: the room plus the next room's far wall 2 m behind the door (wide
    enough that every ray through the door meets it)."""
    parts = room_parts(with_hole=False)
    parts.append(rectangle((-4.0, ROOM[1] + 2.0, -2.0), (1, 0, 0), (0, 0, 1), 12.0, 6.0, (0, -1, 0), step=0.1))
    return merge(parts)


def cameras():
    """(K (3, 3), poses (C, 4, 4)): 12 cameras at 1.5 m on a small circle, looking out horizontally."""
    K = np.array([[60.0, 0, 48], [0, 60.0, 36], [0, 0, 1]])
    poses = []
    centre = np.array([ROOM[0] / 2, ROOM[1] / 2, 1.5])
    for k in range(12):
        angle = 2 * np.pi * k / 12
        forward = np.array([np.cos(angle), np.sin(angle), -0.3])
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        pose = np.eye(4)
        pose[:3, :3] = np.stack([right, down, forward], axis=1)
        pose[:3, 3] = centre + 0.3 * np.array([np.cos(angle), np.sin(angle), 0])
        poses.append(pose)
    return K, np.stack(poses)


