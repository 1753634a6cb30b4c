"""Triangle meshes of a RoomSpec (pure numpy): the room shell with openings, furniture, backdrops.

Every part is built directly in world coordinates (objects get identity transforms in Blender), so a
procedural texture's "Object" coordinates are world metres everywhere and the ground-truth mesh is
just these triangles. Per-corner UVs are world metres projected along the triangle's dominant normal
axis (box mapping), which is what the Workbench image textures are tiled with.
Normals of the shell point into the room; closed solids point outward.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .room import WALL_THICKNESS, FurniturePart, Opening, RoomSpec, wall_frame

CYLINDER_SEGMENTS = 20
BACKDROP_SIDE_EXTENT = 1.0  # how far an opening's outside box reaches past the opening on each side


@dataclass
class MeshPart:
    """One piece of scene geometry: vertices (V, 3) float32 world metres, faces (F, 3) int32,
    uvs (F, 3, 2) float32 per triangle corner, a material name, and whether it casts shadows
    (the boxes outside windows must not block the sun)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    material: str
    casts_shadow: bool = True


def room_parts(spec: RoomSpec) -> list[MeshPart]:
    """All geometry of the room, in a fixed order (shell, openings, furniture)."""
    parts = [
        _part("floor", _quad([0, 0, 0], [spec.length, 0, 0], [spec.length, spec.width, 0], [0, spec.width, 0], up=(0, 0, 1)),
              spec.surfaces["floor"]),
        _part("ceiling", _quad([0, 0, spec.height], [spec.length, 0, spec.height], [spec.length, spec.width, spec.height],
                               [0, spec.width, spec.height], up=(0, 0, -1)), spec.surfaces["ceiling"]),
    ]
    for wall in range(4):
        holes = [o for o in spec.openings if o.wall == wall]
        parts.append(_part(f"wall{wall}", _wall_with_holes(spec, wall, holes), spec.surfaces[f"wall{wall}"]))
    for i, o in enumerate(spec.openings):
        parts.append(_part(f"reveal{i}", _reveal(spec, o), spec.surfaces[f"wall{o.wall}"]))
        parts.append(_part(f"outside{i}", _backdrop(spec, o), o.backdrop_material, casts_shadow=False))
    for i, piece in enumerate(spec.furniture):
        for j, p in enumerate(piece.parts):
            parts.append(_part(f"{piece.kind}{i}_{j}", _furniture_part(p), p.material))
    return parts


def merge_parts(parts: list[MeshPart]) -> tuple[np.ndarray, np.ndarray]:
    """All parts as one mesh: (vertices (V, 3) float32, faces (F, 3) int32)."""
    vertices, faces, offset = [], [], 0
    for p in parts:
        vertices.append(p.vertices)
        faces.append(p.faces + offset)
        offset += len(p.vertices)
    return np.concatenate(vertices).astype(np.float32), np.concatenate(faces).astype(np.int32)


# ------------------------------------------------------------------------------------- primitives

Tris = tuple[np.ndarray, np.ndarray]  # (vertices (V, 3) float64, faces (F, 3) int64)


def _part(name: str, mesh: Tris, material: str, casts_shadow: bool = True) -> MeshPart:
    vertices, faces = mesh
    return MeshPart(name, vertices.astype(np.float32), faces.astype(np.int32), _box_uvs(vertices, faces),
                    material, casts_shadow)


def _quad(a, b, c, d, up) -> Tris:
    """Two triangles of the planar quad a-b-c-d, wound so their normal agrees with `up`."""
    v = np.array([a, b, c, d], np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    normal = np.cross(v[1] - v[0], v[2] - v[0])
    if np.dot(normal, up) < 0:
        f = f[:, ::-1]
    return v, f


def _concat(meshes: list[Tris]) -> Tris:
    vertices, faces, offset = [], [], 0
    for v, f in meshes:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    if not vertices:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return np.concatenate(vertices), np.concatenate(faces)


def box_tris(center, size, yaw: float) -> Tris:
    """Closed box: 6 quads with their own corners (so UVs do not smear across edges), normals outward."""
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    half = np.asarray(size, np.float64) / 2
    quads = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_ax, v_ax = [a for a in range(3) if a != axis]
            corners = []
            for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis], p[u_ax], p[v_ax] = sign * half[axis], du * half[u_ax], dv * half[v_ax]
                corners.append(rot @ p + np.asarray(center, np.float64))
            normal = np.zeros(3)
            normal[axis] = sign
            quads.append(_quad(*corners, up=rot @ normal))
    return _concat(quads)


def cylinder_tris(base_center, radius: float, height: float, segments: int = CYLINDER_SEGMENTS) -> Tris:
    """Closed cylinder standing on `base_center`: side quads plus two fan caps, normals outward."""
    angles = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros(segments)], axis=1) * [radius, radius, 0]
    base = np.asarray(base_center, np.float64)
    bottom, top = ring + base, ring + base + [0, 0, height]
    vertices = np.concatenate([bottom, top, [base, base + [0, 0, height]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    side = np.concatenate([np.stack([i, j, j + segments], 1), np.stack([i, j + segments, i + segments], 1)])
    caps = np.concatenate([np.stack([np.full(segments, 2 * segments), j, i], 1),  # bottom, facing down
                           np.stack([np.full(segments, 2 * segments + 1), i + segments, j + segments], 1)])
    return vertices, np.concatenate([side, caps])


def _furniture_part(p: FurniturePart) -> Tris:
    if p.shape == "cylinder":
        return cylinder_tris(p.center, p.size[0], p.size[2])
    return box_tris(p.center, p.size, p.yaw)


# -------------------------------------------------------------------------------- walls and holes


def _wall_point(spec: RoomSpec, wall: int, u, z, n) -> np.ndarray:
    """World point at distance u along wall `wall`, height z, n metres OUTSIDE its inner plane."""
    start, direction, _ = wall_frame(wall, spec.length, spec.width)
    outward = np.array([direction[1], -direction[0]])
    xy = start + direction * u + outward * n
    return np.array([xy[0], xy[1], z])


def _wall_with_holes(spec: RoomSpec, wall: int, holes: list[Opening]) -> Tris:
    """The inner face of a wall minus its openings, as a grid of rectangles cut at every hole edge."""
    _, direction, span = wall_frame(wall, spec.length, spec.width)
    inward = np.array([-direction[1], direction[0], 0.0])
    us = sorted({0.0, span, *[o.u0 for o in holes], *[o.u1 for o in holes]})
    zs = sorted({0.0, spec.height, *[o.z0 for o in holes], *[o.z1 for o in holes]})
    quads = []
    for ua, ub in zip(us[:-1], us[1:]):
        for za, zb in zip(zs[:-1], zs[1:]):
            um, zm = (ua + ub) / 2, (za + zb) / 2
            if any(o.u0 < um < o.u1 and o.z0 < zm < o.z1 for o in holes):
                continue
            quads.append(_quad(_wall_point(spec, wall, ua, za, 0), _wall_point(spec, wall, ub, za, 0),
                               _wall_point(spec, wall, ub, zb, 0), _wall_point(spec, wall, ua, zb, 0), up=inward))
    return _concat(quads)


def _reveal(spec: RoomSpec, o: Opening) -> Tris:
    """The four faces lining an opening through the wall's thickness, facing into the opening."""
    t = WALL_THICKNESS
    _, direction, _ = wall_frame(o.wall, spec.length, spec.width)
    d3 = np.array([direction[0], direction[1], 0.0])
    P = lambda u, z, n: _wall_point(spec, o.wall, u, z, n)  # noqa: E731
    return _concat([
        _quad(P(o.u0, o.z0, 0), P(o.u0, o.z0, t), P(o.u0, o.z1, t), P(o.u0, o.z1, 0), up=d3),  # left jamb
        _quad(P(o.u1, o.z0, 0), P(o.u1, o.z0, t), P(o.u1, o.z1, t), P(o.u1, o.z1, 0), up=-d3),  # right jamb
        _quad(P(o.u0, o.z0, 0), P(o.u1, o.z0, 0), P(o.u1, o.z0, t), P(o.u0, o.z0, t), up=(0, 0, 1)),  # sill
        _quad(P(o.u0, o.z1, 0), P(o.u1, o.z1, 0), P(o.u1, o.z1, t), P(o.u0, o.z1, t), up=(0, 0, -1)),  # lintel
    ])


def _backdrop(spec: RoomSpec, o: Opening) -> Tris:
    """An open box outside the opening (5 faces, facing inward) so every ray through it hits something:
    a corridor behind a door, a bright view behind a window."""
    t, e, depth = WALL_THICKNESS, BACKDROP_SIDE_EXTENT, o.backdrop_depth
    ua, ub = o.u0 - e, o.u1 + e
    za, zb = (0.0, o.z1 + 0.5) if o.kind == "door" else (o.z0 - e, o.z1 + e)
    na, nb = t, t + depth
    _, direction, _ = wall_frame(o.wall, spec.length, spec.width)
    d3 = np.array([direction[0], direction[1], 0.0])
    towards_room = np.array([-direction[1], direction[0], 0.0])
    P = lambda u, z, n: _wall_point(spec, o.wall, u, z, n)  # noqa: E731
    return _concat([
        _quad(P(ua, za, nb), P(ub, za, nb), P(ub, zb, nb), P(ua, zb, nb), up=towards_room),  # back
        _quad(P(ua, za, na), P(ua, za, nb), P(ua, zb, nb), P(ua, zb, na), up=d3),  # left side
        _quad(P(ub, za, na), P(ub, za, nb), P(ub, zb, nb), P(ub, zb, na), up=-d3),  # right side
        _quad(P(ua, za, na), P(ub, za, na), P(ub, za, nb), P(ua, za, nb), up=(0, 0, 1)),  # floor
        _quad(P(ua, zb, na), P(ub, zb, na), P(ub, zb, nb), P(ua, zb, nb), up=(0, 0, -1)),  # top
    ])


def _box_uvs(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3, 2) per-corner UVs: world metres along the two axes other than the triangle's dominant
    normal axis. Textures thus keep one scale (pixels per metre) on every surface."""
    if len(faces) == 0:
        return np.zeros((0, 3, 2), np.float32)
    tri = vertices[faces]  # (F, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    axis = np.abs(normal).argmax(axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]  # (F, 2) the two axes to use
    uv = np.take_along_axis(tri, np.repeat(keep[:, None, :], 3, axis=1), axis=2)
    return uv.astype(np.float32)
