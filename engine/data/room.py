"""Procedural room descriptions: what is in a synthetic room, decided by a seed (pure numpy, no bpy).

A `RoomSpec` is plain data (JSON-serialisable) so it can be written to `room.json`, compared between
runs and turned into geometry (geometry.py), camera paths (trajectory.py) and Blender objects
(blender_scene.py) separately. Everything random comes from one `numpy.random.Generator` seeded with
the room's seed, always drawn in the same order, so a seed always gives the same room.

World frame: metres, Z up; the room spans [0, length] x [0, width] x [0, height]; the floor is z = 0.
Walls are numbered 0: y = 0, 1: x = length, 2: y = width, 3: x = 0; a position `u` along a wall is
measured from its start corner going counter-clockwise seen from above.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Optional

import numpy as np

from .path_loop import PathLoop, make_path_loop

WALL_THICKNESS = 0.12
PATTERNS = ("noise", "voronoi", "brick", "wave", "checker", "marble")
# Surface mixes of `generate_room`. "textured": every surface carries a visible pattern (the rooms the
# v1/v2 weights were trained on). "mixed": like real rooms, a share of walls and ceilings is plain
# paint (almost no texture: stereo finds nothing there) and a share of furniture is dark or glossy.
SURFACE_MIXES = ("textured", "mixed")
PLAIN_PAINT_SHARE = 0.5  # walls / ceilings turned plain in a "mixed" room
DARK_OR_GLOSSY_SHARE = 0.3  # furniture / item materials turned dark or glossy in a "mixed" room
# Clutter levels of `generate_room`. "normal": a few items on tables and low cabinets (the rooms so
# far). "dense": as lived-in rooms are, more small things on every table and cabinet top and some on
# the floor along the walls: thin, small geometry that fusion and stereo must not smear away.
CLUTTER_LEVELS = ("normal", "dense")
FLOOR_ITEMS_PER_M2 = 0.3  # "dense": small things standing on the floor (at most this many per m^2)


@dataclass
class MaterialSpec:
    """A procedural surface: a pattern mixing two colours, modulated by fine noise for texture."""

    name: str
    pattern: str  # one of PATTERNS
    colors: list[list[float]]  # three linear RGB colours: pattern A, pattern B, fine-noise tint
    scale: float  # pattern repeats per metre
    detail_scale: float  # fine-noise frequency per metre (gives SIFT something at pixel scale)
    detail_strength: float  # 0..1 how much the fine noise tints the colour
    speckle_scale: float  # spots per metre: small high-contrast blobs, what SIFT detects best
    speckle_strength: float  # 0..1 opacity of the spots (0 = none)
    roughness: float
    rotation: float  # pattern rotation about the surface normal (radians)
    emission: float = 0.0  # > 0 for window backdrops (a bright view outside)


@dataclass
class Opening:
    """A door or window: a rectangular hole in a wall, with a backdrop box behind it."""

    kind: str  # "door" or "window"
    wall: int
    u0: float
    u1: float
    z0: float
    z1: float
    backdrop_depth: float  # how far the outside box reaches beyond the wall
    backdrop_material: str


@dataclass
class FurniturePart:
    """One primitive of a piece of furniture, in world coordinates."""

    shape: str  # "box" or "cylinder"
    center: list[float]  # box: its centre; cylinder: the centre of its bottom disc
    size: list[float]  # box: (sx, sy, sz) along its local axes; cylinder: (radius, radius, height)
    yaw: float
    material: str


@dataclass
class FurnitureSpec:
    kind: str  # "cabinet", "shelf", "table", "cylinder", "crate", "picture", "item" (small thing on the floor)
    center: list[float]  # footprint centre (x, y)
    footprint: list[float]  # (size along local x, size along local y)
    yaw: float
    height: float
    parts: list[FurniturePart] = field(default_factory=list)


@dataclass
class LightSpec:
    kind: str  # "POINT", "AREA" or "SUN"
    location: list[float]
    direction: list[float]  # unit vector the light shines along (area and sun; ignored for points)
    power: float  # W for point/area, W/m^2 (strength) for the sun
    kelvin: float
    color: list[float]  # linear RGB of `kelvin`
    size: float = 0.0  # area light edge / point and sun soft-shadow radius


@dataclass
class RoomSpec:
    seed: int
    length: float  # x extent (m)
    width: float  # y extent (m)
    height: float
    materials: dict[str, MaterialSpec]
    surfaces: dict[str, str]  # "floor", "ceiling", "wall0".."wall3" -> material name
    openings: list[Opening]
    furniture: list[FurnitureSpec]
    lights: list[LightSpec]
    world_color: list[float]
    world_strength: float
    path: PathLoop

    def to_json(self) -> dict:
        return asdict(self)


# ------------------------------------------------------------------------------------------ sampling


def generate_room(seed: int, surfaces: str = "textured", clutter: str = "normal") -> RoomSpec:
    """The room for `seed`: 3-8 m x 3-8 m, 2.4-3.2 m high, with openings, furniture, lights, materials.

    surfaces: one of SURFACE_MIXES. "mixed" repaints some materials afterwards from a separate random
    stream, so the geometry, cameras and other materials of a seed are the same under both mixes.
    clutter: one of CLUTTER_LEVELS. "dense" adds small items afterwards from another stream: the rest
    of the room and the camera walk (which never aims at the items) stay those of the seed.
    """
    if surfaces not in SURFACE_MIXES:
        raise ValueError(f"surfaces must be one of {SURFACE_MIXES}, got {surfaces!r}")
    if clutter not in CLUTTER_LEVELS:
        raise ValueError(f"clutter must be one of {CLUTTER_LEVELS}, got {clutter!r}")
    spec = _generate_textured_room(seed)
    if surfaces == "mixed":
        _repaint_mixed(spec, np.random.default_rng([seed, 2]))
    if clutter == "dense":
        _add_dense_clutter(spec, np.random.default_rng([seed, 5]))
    return spec


def _add_dense_clutter(spec: RoomSpec, rng: np.random.Generator) -> None:
    """In place: more items on every table and low cabinet, and small things on the floor."""
    items = sorted(name for name in spec.materials if name.startswith("item"))

    def pick_material(pool: str, palette: str = "any") -> str:
        return items[int(rng.integers(0, len(items)))]

    for piece in list(spec.furniture):
        if piece.kind == "table" or (piece.kind == "cabinet" and piece.height < 1.3):
            w, d = piece.footprint
            sx, sy = (0.85, 0.85) if piece.kind == "table" else (0.9, 0.8)  # as the first items were placed
            bottom = [p.center[2] - (p.size[2] / 2 if p.shape == "box" else 0.0) for p in piece.parts]
            taken = [_local_footprint(piece, p) for p, z in zip(piece.parts, bottom) if z >= piece.height - 1e-6]
            piece.parts += _clutter(rng, piece, piece.height, w * sx, d * sy, pick_material,
                                    count=int(rng.integers(3, 8)), taken=taken)
    path_xy = np.asarray(spec.path.points)[:, :2]
    n_floor = int(rng.integers(2, 2 + int(FLOOR_ITEMS_PER_M2 * spec.length * spec.width)))
    placed = 0
    for _ in range(n_floor * 20):
        if placed >= n_floor:
            break
        r = float(rng.uniform(0.06, 0.2))
        x, y = rng.uniform(0.1 + r, spec.length - 0.1 - r), rng.uniform(0.1 + r, spec.width - 0.1 - r)
        yaw = float(rng.uniform(-np.pi, np.pi))
        height = float(rng.uniform(0.05, 0.45))
        piece = FurnitureSpec("item", [float(x), float(y)], [2 * r, 2 * r], yaw, height)
        if not _fits(piece, spec.furniture, path_xy, spec.openings, spec.length, spec.width):
            continue
        material = pick_material("item")
        if rng.random() < 0.5:
            piece.parts = [FurniturePart("cylinder", [float(x), float(y), 0.0], [r, r, height], 0.0, material)]
        else:
            piece.parts = [FurniturePart("box", [float(x), float(y), height / 2], [2 * r, 2 * r * float(rng.uniform(0.6, 1.0)),
                                                                                   height], yaw, material)]
        spec.furniture.append(piece)
        placed += 1


def _local_footprint(piece: FurnitureSpec, part: FurniturePart) -> tuple[float, float, float]:
    """(local x, local y, radius) of a part standing on `piece`, for keeping new items clear of it."""
    c, s = np.cos(piece.yaw), np.sin(piece.yaw)
    dx, dy = part.center[0] - piece.center[0], part.center[1] - piece.center[1]
    radius = part.size[0] if part.shape == "cylinder" else float(np.hypot(part.size[0], part.size[1])) / 2
    return float(c * dx + s * dy), float(-s * dx + c * dy), float(radius)


def _repaint_mixed(spec: RoomSpec, rng: np.random.Generator) -> None:
    """In place: plain paint on a share of walls / ceilings, dark or glossy furniture and items."""
    for name, m in sorted(spec.materials.items()):
        if name.startswith(("wall", "ceiling")) and rng.random() < PLAIN_PAINT_SHARE:
            # One colour with a barely visible tint: real paint, what plane-sweep stereo cannot match.
            base = np.asarray(m.colors[0])
            m.colors = [list(map(float, base)), list(map(float, np.clip(base * rng.uniform(0.97, 1.03), 0, 1))),
                        list(map(float, np.clip(base * 0.9, 0, 1)))]
            m.detail_strength = float(rng.uniform(0.0, 0.06))
            m.speckle_strength = 0.0
            if m.pattern == "brick":  # Cycles draws brick mortar at half brightness: lines, not paint
                m.pattern = "noise"
        elif name.startswith(("furn", "item")) and rng.random() < DARK_OR_GLOSSY_SHARE:
            if rng.random() < 0.5:  # dark: little signal above the sensor noise
                m.colors = [list(map(float, np.clip(np.asarray(c) * rng.uniform(0.05, 0.15), 0, 1))) for c in m.colors]
            m.roughness = float(rng.uniform(0.02, 0.15))  # glossy (Cycles shows the highlights)
            m.detail_strength = float(min(m.detail_strength, rng.uniform(0.0, 0.2)))
            m.speckle_strength = 0.0


def _generate_textured_room(seed: int) -> RoomSpec:
    rng = np.random.default_rng(seed)
    length, width = (float(round(x, 3)) for x in rng.uniform(3.0, 8.0, 2))
    height = float(round(rng.uniform(2.4, 3.2), 3))
    materials: dict[str, MaterialSpec] = {}

    def new_material(prefix: str, palette: str, emission: float = 0.0) -> str:
        name = f"{prefix}{len(materials):02d}"
        materials[name] = _sample_material(rng, name, palette, emission)
        return name

    # Furniture and small items draw from fixed pools: a few dozen materials keep Blender's shader
    # compilation cheap while rooms still look varied.
    pools = {
        "furn": [new_material("furn", "any") for _ in range(int(rng.integers(3, 7)))],
        "item": [new_material("item", "any") for _ in range(int(rng.integers(6, 13)))],
    }

    def pick_material(pool: str, palette: str = "any") -> str:  # palette kept for call symmetry
        names = pools[pool]
        return names[int(rng.integers(0, len(names)))]

    wall_material = new_material("wall", "wall")
    surfaces = {"floor": new_material("floor", "floor"), "ceiling": new_material("ceiling", "ceiling")}
    # Usually one paint for all walls, sometimes an accent wall.
    accent = int(rng.integers(0, 4)) if rng.random() < 0.35 else -1
    for w in range(4):
        surfaces[f"wall{w}"] = new_material("wall", "wall") if w == accent else wall_material

    openings = _sample_openings(rng, length, width, height, new_material)
    path = make_path_loop(rng, length, width)
    furniture = _sample_furniture(rng, length, width, height, openings, path, pick_material)
    art = [new_material("art", "any") for _ in range(int(rng.integers(2, 5)))]
    furniture += _sample_pictures(rng, length, width, height, openings, furniture, art)
    lights = _sample_lights(rng, length, width, height, openings)
    world_color = [float(x) for x in _kelvin_to_rgb(float(rng.uniform(5500, 9000)))]
    return RoomSpec(seed, length, width, height, materials, surfaces, openings, furniture, lights,
                    world_color, float(rng.uniform(0.3, 1.0)), path)


def wall_frame(wall: int, length: float, width: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(start corner (2,), unit direction along the wall (2,), wall length) for wall 0..3.

    The room interior is to the LEFT of the direction (counter-clockwise walk), i.e. the inward normal
    is (-dy, dx).
    """
    corners = np.array([[0.0, 0.0], [length, 0.0], [length, width], [0.0, width]])
    start, end = corners[wall], corners[(wall + 1) % 4]
    span = float(np.linalg.norm(end - start))
    return start, (end - start) / span, span


def _sample_material(rng: np.random.Generator, name: str, palette: str, emission: float) -> MaterialSpec:
    pattern = str(rng.choice(PATTERNS))
    base = _palette_color(rng, palette)
    # The second colour is a lighter/darker variant (sometimes a contrasting hue) so patterns show.
    if rng.random() < 0.3:
        second = _palette_color(rng, "any")
    else:
        # Never nearly equal to the base: a visible pattern is what SIFT and the network lock onto.
        factor = rng.uniform(0.4, 0.7) if rng.random() < 0.5 else rng.uniform(1.35, 1.8)
        second = np.clip(base * factor + rng.normal(0, 0.03, 3), 0.01, 0.95)
    tint = np.clip(base * rng.uniform(0.3, 0.8), 0.005, 0.9)
    scale = {"floor": rng.uniform(1.0, 4.0), "wall": rng.uniform(0.8, 3.0)}.get(palette, rng.uniform(1.5, 6.0))
    return MaterialSpec(
        name=name,
        pattern=pattern,
        colors=[[float(c) for c in base], [float(c) for c in second], [float(c) for c in tint]],
        scale=float(scale),
        detail_scale=float(rng.uniform(10.0, 30.0)),
        detail_strength=float(rng.uniform(0.35, 0.7)),
        speckle_scale=float(rng.uniform(5.0, 15.0)),
        speckle_strength=float(rng.uniform(0.6, 1.0)) if rng.random() < 0.85 else 0.0,
        roughness=float(rng.uniform(0.35, 0.95)),
        rotation=float(rng.uniform(0, np.pi)),
        emission=emission,
    )


def _palette_color(rng: np.random.Generator, palette: str) -> np.ndarray:
    """A linear-RGB colour typical for the surface type (walls pale, floors wood/stone/carpet...)."""
    hsv = {
        "wall": (rng.uniform(0, 1), rng.uniform(0.02, 0.35), rng.uniform(0.45, 0.85)),
        "ceiling": (rng.uniform(0, 1), rng.uniform(0.0, 0.12), rng.uniform(0.65, 0.9)),
        "floor": (rng.uniform(0.02, 0.12), rng.uniform(0.2, 0.7), rng.uniform(0.15, 0.6)),
        "sky": (rng.uniform(0.5, 0.65), rng.uniform(0.2, 0.6), rng.uniform(0.7, 1.0)),
    }.get(palette, (rng.uniform(0, 1), rng.uniform(0.1, 0.8), rng.uniform(0.1, 0.8)))
    srgb = _hsv_to_rgb(*hsv)
    return np.clip(srgb, 0, 1) ** 2.2  # sRGB-ish -> linear, as Blender colours are linear


def _hsv_to_rgb(h: float, s: float, v: float) -> np.ndarray:
    k = (np.array([5.0, 3.0, 1.0]) + h * 6.0) % 6.0
    return v - v * s * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)


def _kelvin_to_rgb(kelvin: float) -> np.ndarray:
    """Approximate linear RGB of a black body (Tanner Helland's fit), normalised to max 1."""
    t = kelvin / 100.0
    r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
    g = 99.4708025861 * np.log(t) - 161.1195681661 if t <= 66 else 288.1221695283 * (t - 60) ** -0.0755148492
    b = 255.0 if t >= 66 else (0.0 if t <= 19 else 138.5177312231 * np.log(t - 10) - 305.0447927307)
    rgb = np.clip(np.array([r, g, b]) / 255.0, 0.0, 1.0) ** 2.2
    return rgb / rgb.max()


def _sample_openings(rng, length, width, height, new_material) -> list[Opening]:
    openings: list[Opening] = []
    taken: dict[int, list[tuple[float, float]]] = {w: [] for w in range(4)}

    def place(kind: str, span: float, z0: float, z1: float) -> Optional[Opening]:
        for _ in range(20):
            wall = int(rng.integers(0, 4))
            _, _, wall_len = wall_frame(wall, length, width)
            if wall_len - 0.6 < span:
                continue
            u0 = float(rng.uniform(0.3, wall_len - 0.3 - span))
            if any(u0 < b + 0.3 and u0 + span > a - 0.3 for a, b in taken[wall]):
                continue
            taken[wall].append((u0, u0 + span))
            depth = float(rng.uniform(1.2, 2.0)) if kind == "door" else float(rng.uniform(1.5, 3.5))
            palette, emission = ("sky", float(rng.uniform(2.0, 5.0))) if kind == "window" else ("any", 0.0)
            material = new_material("outside", palette, emission)
            return Opening(kind, wall, round(u0, 3), round(u0 + span, 3), round(z0, 3), round(z1, 3), depth, material)
        return None

    for _ in range(int(rng.integers(1, 3))):
        door = place("door", float(rng.uniform(0.8, 1.0)), 0.0, float(rng.uniform(2.0, min(2.15, height - 0.15))))
        if door:
            openings.append(door)
    for _ in range(int(rng.integers(0, 4))):
        sill = float(rng.uniform(0.75, 1.0))
        top = float(min(rng.uniform(1.9, 2.3), height - 0.2))
        window = place("window", float(rng.uniform(0.8, 2.0)), sill, top)
        if window:
            openings.append(window)
    return openings


# ---------------------------------------------------------------------------------------- furniture


def _sample_furniture(rng, length, width, height, openings, path: PathLoop, pick_material) -> list[FurnitureSpec]:
    pieces: list[FurnitureSpec] = []
    path_xy = np.asarray(path.points)[:, :2]
    area = length * width
    n_wall = int(rng.integers(2, 4 + int(area / 8)))
    n_free = int(rng.integers(1, 3 + int(area / 15)))
    for attempt in range(n_wall * 15):
        if sum(p.kind in ("cabinet", "shelf") for p in pieces) >= n_wall:
            break
        kind = "shelf" if rng.random() < 0.5 else "cabinet"
        piece = _wall_piece(rng, kind, length, width, height, openings, pick_material)
        if piece and _fits(piece, pieces, path_xy, openings, length, width):
            pieces.append(piece)
    free_done = 0
    for attempt in range(n_free * 25):
        if free_done >= n_free:
            break
        kind = str(rng.choice(["table", "table", "cylinder", "crate"]))
        piece = _free_piece(rng, kind, length, width, height, pick_material)
        if _fits(piece, pieces, path_xy, openings, length, width):
            pieces.append(piece)
            free_done += 1
    return pieces


def _wall_piece(rng, kind, length, width, height, openings, pick_material) -> Optional[FurnitureSpec]:
    wall = int(rng.integers(0, 4))
    start, direction, wall_len = wall_frame(wall, length, width)
    inward = np.array([-direction[1], direction[0]])
    if kind == "shelf":
        w, d, h = rng.uniform(0.6, 1.6), rng.uniform(0.28, 0.42), rng.uniform(1.0, min(2.2, height - 0.2))
    else:
        w, d, h = rng.uniform(0.5, 2.0), rng.uniform(0.35, 0.65), rng.uniform(0.45, min(2.0, height - 0.2))
    if w > wall_len - 0.2:
        return None
    u = rng.uniform(0.1 + w / 2, wall_len - 0.1 - w / 2)
    # Under a window only low pieces fit.
    for o in openings:
        if o.wall == wall and o.kind == "window" and u + w / 2 > o.u0 and u - w / 2 < o.u1:
            h = min(h, o.z0 - 0.05)
    if h < 0.35:
        return None
    gap = rng.uniform(0.01, 0.08)
    center = start + direction * u + inward * (gap + d / 2)
    yaw = float(np.arctan2(direction[1], direction[0]))  # local x along the wall, local +y into the room
    material = pick_material("furn", "any")
    piece = FurnitureSpec(kind, [float(center[0]), float(center[1])], [float(w), float(d)], yaw, float(h))
    piece.parts = (_shelf_parts if kind == "shelf" else _cabinet_parts)(rng, piece, material, pick_material)
    return piece


def _free_piece(rng, kind, length, width, height, pick_material) -> FurnitureSpec:
    x, y = rng.uniform(0.3, length - 0.3), rng.uniform(0.3, width - 0.3)
    yaw = float(rng.uniform(-np.pi, np.pi)) if rng.random() < 0.5 else float(rng.integers(0, 4) * np.pi / 2)
    material = pick_material("furn", "any")
    if kind == "table":
        w, d = rng.uniform(0.7, 1.8), rng.uniform(0.6, 1.0)
        piece = FurnitureSpec(kind, [float(x), float(y)], [float(w), float(d)], yaw, float(rng.uniform(0.68, 0.78)))
        piece.parts = _table_parts(rng, piece, material, pick_material)
    elif kind == "cylinder":
        r = rng.uniform(0.12, 0.35)
        piece = FurnitureSpec(kind, [float(x), float(y)], [float(2 * r), float(2 * r)], 0.0, float(rng.uniform(0.3, 1.3)))
        piece.parts = [FurniturePart("cylinder", [float(x), float(y), 0.0], [float(r), float(r), piece.height], 0.0, material)]
    else:
        s = rng.uniform(0.25, 0.8, 3)
        piece = FurnitureSpec(kind, [float(x), float(y)], [float(s[0]), float(s[1])], yaw, float(s[2]))
        piece.parts = [FurniturePart("box", [float(x), float(y), float(s[2] / 2)], [float(v) for v in s], yaw, material)]
        if rng.random() < 0.5:  # a second crate stacked on top
            t = s * rng.uniform(0.5, 0.9, 3)
            piece.parts.append(FurniturePart("box", [float(x), float(y), float(s[2] + t[2] / 2)], [float(v) for v in t],
                                             yaw + float(rng.uniform(-0.4, 0.4)), pick_material("furn", "any")))
    return piece


def _local_to_world(piece: FurnitureSpec, lx: float, ly: float) -> tuple[float, float]:
    c, s = np.cos(piece.yaw), np.sin(piece.yaw)
    return float(piece.center[0] + c * lx - s * ly), float(piece.center[1] + s * lx + c * ly)


def _box(piece: FurnitureSpec, lx, ly, z, sx, sy, sz, material, yaw_offset=0.0) -> FurniturePart:
    """Box part whose centre is at local (lx, ly) and height z (centre) of the piece."""
    x, y = _local_to_world(piece, lx, ly)
    return FurniturePart("box", [x, y, float(z)], [float(sx), float(sy), float(sz)], piece.yaw + yaw_offset, material)


def _cabinet_parts(rng, piece, material, pick_material) -> list[FurniturePart]:
    w, d = piece.footprint
    h = piece.height
    parts = [_box(piece, 0, 0, h / 2, w, d, h, material)]
    # Door/drawer fronts: thin panels in a second material make the front readable.
    front = pick_material("furn", "any")
    n = int(rng.integers(1, 4))
    for i in range(n):
        cx = -w / 2 + (i + 0.5) * w / n
        parts.append(_box(piece, cx, d / 2 + 0.01, h / 2, w / n - 0.04, 0.02, h - 0.1, front))
    parts += _clutter(rng, piece, h, w * 0.9, d * 0.8, pick_material) if h < 1.3 else []
    return parts


def _shelf_parts(rng, piece, material, pick_material) -> list[FurniturePart]:
    w, d = piece.footprint
    h, t = piece.height, 0.025
    parts = [
        _box(piece, -w / 2 + t / 2, 0, h / 2, t, d, h, material),
        _box(piece, w / 2 - t / 2, 0, h / 2, t, d, h, material),
        _box(piece, 0, -d / 2 + 0.005, h / 2, w, 0.01, h, material),  # back panel
    ]
    n_boards = int(rng.integers(2, 6))
    levels = np.linspace(0.05, h - t / 2, n_boards + 1)
    for z in levels:
        parts.append(_box(piece, 0, 0, z, w - 2 * t, d, t, material))
    # Books and boxes on the boards (not the top one when it is above eye height).
    for lower, upper in zip(levels[:-1], levels[1:]):
        x = -w / 2 + t + 0.02
        gap = upper - lower - t
        while x < w / 2 - t - 0.06 and rng.random() < 0.85:
            bw = rng.uniform(0.02, 0.12) if rng.random() < 0.7 else rng.uniform(0.1, 0.25)
            if x + bw > w / 2 - t:
                break
            bh = rng.uniform(0.4, 0.95) * gap
            bd = rng.uniform(0.5, 0.95) * d
            parts.append(_box(piece, x + bw / 2, -d / 2 + bd / 2 + 0.01, lower + t / 2 + bh / 2, bw, bd, bh,
                              pick_material("item", "any")))
            x += bw + (rng.uniform(0.0, 0.02) if rng.random() < 0.8 else rng.uniform(0.05, 0.3))
    return parts


def _table_parts(rng, piece, material, pick_material) -> list[FurniturePart]:
    w, d = piece.footprint
    h, t, leg = piece.height, float(rng.uniform(0.025, 0.05)), float(rng.uniform(0.04, 0.07))
    parts = [_box(piece, 0, 0, h - t / 2, w, d, t, material)]
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(_box(piece, sx * (w / 2 - leg), sy * (d / 2 - leg), (h - t) / 2, leg, leg, h - t, material))
    return parts + _clutter(rng, piece, h, w * 0.85, d * 0.85, pick_material)


def _clutter(rng, piece, top, w, d, pick_material, count: Optional[int] = None,
             taken: Optional[list[tuple[float, float, float]]] = None) -> list[FurniturePart]:
    """Small boxes and cylinders standing on a surface at height `top` of size w x d (local frame);
    `count` items (default 1-5), clear of the `taken` (local x, local y, radius) spots."""
    parts: list[FurniturePart] = []
    placed: list[tuple[float, float, float]] = list(taken or [])
    for _ in range(int(rng.integers(1, 6)) if count is None else count):
        for _try in range(8):
            r = rng.uniform(0.04, 0.14)
            lx, ly = rng.uniform(-w / 2 + r, w / 2 - r), rng.uniform(-d / 2 + r, d / 2 - r)
            if all((lx - px) ** 2 + (ly - py) ** 2 > (r + pr + 0.02) ** 2 for px, py, pr in placed):
                break
        else:
            continue
        placed.append((lx, ly, r))
        hgt = rng.uniform(0.04, 0.35)
        material = pick_material("item", "any")
        if rng.random() < 0.5:
            x, y = _local_to_world(piece, lx, ly)
            parts.append(FurniturePart("cylinder", [x, y, float(top)], [float(r * 0.8), float(r * 0.8), float(hgt)], 0.0, material))
        else:
            parts.append(_box(piece, lx, ly, top + hgt / 2, r * 1.4, r * rng.uniform(0.8, 1.4), hgt, material,
                              yaw_offset=float(rng.uniform(-0.6, 0.6))))
    return parts


def _footprint_corners(piece: FurnitureSpec, pad: float = 0.0) -> np.ndarray:
    hw, hd = piece.footprint[0] / 2 + pad, piece.footprint[1] / 2 + pad
    return np.array([_local_to_world(piece, sx * hw, sy * hd) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def _point_box_distance(piece: FurnitureSpec, points: np.ndarray) -> np.ndarray:
    """Distance (N,) from 2D points (N, 2) to the piece's footprint rectangle (0 inside)."""
    c, s = np.cos(piece.yaw), np.sin(piece.yaw)
    rel = points - np.asarray(piece.center)
    local = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)
    excess = np.maximum(np.abs(local) - np.asarray(piece.footprint) / 2, 0.0)
    return np.linalg.norm(excess, axis=1)


def _rects_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex quads (4, 2)."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def _fits(piece: FurnitureSpec, placed: list[FurnitureSpec], path_xy: np.ndarray, openings: list[Opening],
          length: float, width: float) -> bool:
    corners = _footprint_corners(piece)
    if corners.min() < 0.0 or np.any(corners[:, 0] > length) or np.any(corners[:, 1] > width):
        return False
    # The camera walks the path: keep furniture (and its clutter) an arm's length away from it.
    if _point_box_distance(piece, path_xy).min() < 0.45:
        return False
    padded = _footprint_corners(piece, pad=0.05)
    if any(_rects_overlap(padded, _footprint_corners(other, pad=0.05)) for other in placed):
        return False
    for o in openings:
        if o.kind != "door":
            continue
        # Keep a 1 m deep strip in front of each door clear.
        start, direction, _ = wall_frame(o.wall, length, width)
        inward = np.array([-direction[1], direction[0]])
        a, b = start + direction * (o.u0 - 0.1), start + direction * (o.u1 + 0.1)
        door_zone = np.array([a, b, b + inward * 1.0, a + inward * 1.0])
        if _rects_overlap(corners, door_zone):
            return False
    return True


# ------------------------------------------------------------------------------------------- lights


def _sample_lights(rng, length, width, height, openings) -> list[LightSpec]:
    """Ceiling panels, lamps and sometimes sun through a window; power scales with the floor area so
    small and large rooms come out similarly exposed."""
    area = length * width
    lights: list[LightSpec] = []

    def light(kind, location, direction, power, size) -> LightSpec:
        kelvin = float(rng.uniform(2700, 6500))
        return LightSpec(kind, [float(v) for v in location], [float(v) for v in direction], float(power), kelvin,
                         [float(c) for c in _kelvin_to_rgb(kelvin)], float(size))

    n_panels = int(rng.integers(1, 2 + int(area / 18)))
    for _ in range(n_panels):
        loc = (rng.uniform(0.2, 0.8) * length, rng.uniform(0.2, 0.8) * width, height - 0.02)
        lights.append(light("AREA", loc, (0, 0, -1), rng.uniform(12, 30) * area / n_panels, rng.uniform(0.4, 1.2)))
    for _ in range(int(rng.integers(0, 3))):
        loc = (rng.uniform(0.4, length - 0.4), rng.uniform(0.4, width - 0.4), rng.uniform(1.2, height - 0.3))
        lights.append(light("POINT", loc, (0, 0, -1), rng.uniform(3, 10) * area, rng.uniform(0.05, 0.3)))
    windows = [o for o in openings if o.kind == "window"]
    if windows and rng.random() < 0.6:
        o = windows[int(rng.integers(0, len(windows)))]
        _, direction, _ = wall_frame(o.wall, length, width)
        inward = np.array([-direction[1], direction[0]])
        elevation = rng.uniform(np.radians(15), np.radians(50))
        side = rng.uniform(-0.6, 0.6)
        d = np.array([*(np.cos(elevation) * (inward * np.cos(side) + direction * np.sin(side))), -np.sin(elevation)])
        lights.append(light("SUN", (0, 0, height + 5), d / np.linalg.norm(d), rng.uniform(1.5, 4.0), rng.uniform(0.01, 0.05)))
    return lights


def _sample_pictures(rng, length, width, height, openings, furniture, art: list[str]) -> list[FurnitureSpec]:
    """Pictures and posters: thin panels on the walls, clear of openings and of furniture in front."""
    pictures: list[FurnitureSpec] = []
    for wall in range(4):
        start, direction, span = wall_frame(wall, length, width)
        inward = np.array([-direction[1], direction[0]])
        taken = [(o.u0 - 0.15, o.u1 + 0.15, o.z0, o.z1) for o in openings if o.wall == wall]
        for piece in furniture:  # what stands against this wall, as (u range, up to its height)
            rel = _footprint_corners(piece) - start
            if (rel @ inward).min() < 0.8:
                u = rel @ direction
                taken.append((u.min() - 0.05, u.max() + 0.05, 0.0, piece.height + 0.1))
        for _ in range(int(rng.integers(0, 3))):
            w, h = rng.uniform(0.3, 1.1), rng.uniform(0.3, 0.8)
            z0 = rng.uniform(0.9, 1.5)
            if z0 + h > height - 0.15 or w > span - 0.4:
                continue
            u0 = rng.uniform(0.2, span - 0.2 - w)
            if any(u0 < b and u0 + w > a and z0 < z1 and z0 + h > z0_ for a, b, z0_, z1 in taken):
                continue
            taken.append((u0 - 0.1, u0 + w + 0.1, z0 - 0.1, z0 + h + 0.1))
            depth = 0.025
            center = start + direction * (u0 + w / 2) + inward * depth / 2
            yaw = float(np.arctan2(direction[1], direction[0]))
            piece = FurnitureSpec("picture", [float(center[0]), float(center[1])], [float(w), depth], yaw, float(z0 + h))
            material = art[int(rng.integers(0, len(art)))]
            piece.parts = [_box(piece, 0, 0, z0 + h / 2, w, depth, h, material)]
            pictures.append(piece)
    return pictures
