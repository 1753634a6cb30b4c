"""Triangle-mesh files: PLY (read ascii / binary either endian, write binary little-endian) and OBJ (write).

One small module shared by the whole engine, so every mesh file we write (ground truth, predictions,
exports) is read back the same way. Only what a triangle mesh needs is kept: vertex positions,
triangles, optional per-vertex normals and colours, and named per-vertex float attributes (e.g. how
well each vertex was observed, engine/stereo/vertex_evidence.py), stored in PLY as extra float vertex
properties. Polygons with more than three corners are fan-triangulated on read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Optional, Union

import numpy as np

PathLike = Union[str, Path]

# PLY scalar type names (both spellings the format allows) -> numpy dtype character codes.
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


@dataclass
class Mesh:
    """A triangle mesh in world metres.

    vertices (V, 3) float32; faces (F, 3) int32 (indices into vertices); normals (V, 3) float32 or
    None; colors (V, 3) float32 in 0..1 or None; attributes: name -> (V,) float32 per-vertex values
    (PLY keeps them as float vertex properties; OBJ has no place for them).
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: Optional[np.ndarray] = None
    colors: Optional[np.ndarray] = None
    attributes: dict[str, np.ndarray] = field(default_factory=dict)


# Vertex properties with a fixed meaning; every other scalar vertex property is read as an attribute.
_POSITION_NAMES = ("x", "y", "z")
_NORMAL_NAMES = ("nx", "ny", "nz")
_COLOUR_NAMES = (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue"))
_RESERVED_NAMES = frozenset(_POSITION_NAMES + _NORMAL_NAMES + sum(_COLOUR_NAMES, ()) + ("alpha",))


@dataclass
class _Property:
    name: str
    dtype: str  # numpy code for a scalar property, or for the items of a list property
    count_dtype: Optional[str] = None  # numpy code of a list property's length prefix; None for scalars


@dataclass
class _Element:
    name: str
    count: int
    properties: list[_Property]


# ----------------------------------------------------------------------------------------------- write


def write_ply(
    path: PathLike,
    vertices: np.ndarray,
    faces: Optional[np.ndarray] = None,
    normals: Optional[np.ndarray] = None,
    colors: Optional[np.ndarray] = None,
    attributes: Optional[dict[str, np.ndarray]] = None,
) -> None:
    """Write a binary little-endian PLY.

    vertices (V, 3); faces (F, 3) or None for a point cloud; normals (V, 3) or None;
    colors (V, 3) as float 0..1 or uint8 0..255, or None; attributes: name -> (V,) values, or None.
    Positions, normals and attributes are stored as float32, colours as uchar red/green/blue, faces
    as `list uchar int vertex_indices`.
    """
    vertices = np.asarray(vertices, dtype=np.float32).reshape(-1, 3)
    n_vertices = len(vertices)
    fields: list[tuple[str, str]] = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float32).reshape(-1, 3)
        _check_rows("normals", normals, n_vertices)
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if colors is not None:
        colors = _colors_to_uint8(colors)
        _check_rows("colors", colors, n_vertices)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    attributes = _checked_attributes(attributes or {}, n_vertices)
    fields += [(name, "<f4") for name in attributes]

    vertex_data = np.empty(n_vertices, dtype=np.dtype(fields))
    for axis, name in enumerate("xyz"):
        vertex_data[name] = vertices[:, axis]
    if normals is not None:
        for axis, name in enumerate(("nx", "ny", "nz")):
            vertex_data[name] = normals[:, axis]
    if colors is not None:
        for axis, name in enumerate(("red", "green", "blue")):
            vertex_data[name] = colors[:, axis]
    for name, values in attributes.items():
        vertex_data[name] = values

    header = ["ply", "format binary_little_endian 1.0", "comment written by VoRTX for Blender",
              f"element vertex {n_vertices}", "property float x", "property float y", "property float z"]
    if normals is not None:
        header += ["property float nx", "property float ny", "property float nz"]
    if colors is not None:
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    header += [f"property float {name}" for name in attributes]

    face_data = None
    if faces is not None:
        faces = np.asarray(faces).reshape(-1, 3)
        if len(faces) and (faces.min() < 0 or faces.max() >= n_vertices):
            raise ValueError(f"face indices must lie in [0, {n_vertices}); got {faces.min()}..{faces.max()}")
        face_data = np.empty(len(faces), dtype=np.dtype([("n", "u1"), ("v", "<i4", (3,))]))
        face_data["n"] = 3
        face_data["v"] = faces
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    header.append("end_header")

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vertex_data.tobytes())
        if face_data is not None:
            f.write(face_data.tobytes())


def write_obj(
    path: PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: Optional[np.ndarray] = None,
    colors: Optional[np.ndarray] = None,
    uvs: Optional[np.ndarray] = None,
    material: Optional[tuple[str, str]] = None,
) -> None:
    """Write a Wavefront OBJ. vertices (V, 3); faces (F, 3) 0-based; normals (V, 3) or None;
    colors (V, 3) float 0..1 or uint8, written as the common `v x y z r g b` extension (read by
    Blender, MeshLab and Open3D); uvs (V, 2) per-vertex texture coordinates (v up, as OBJ wants) or
    None; material: (MTL file name, material name) for `mtllib` / `usemtl`, or None."""
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    lines = ["# written by VoRTX for Blender"]
    if material is not None:
        lines.append(f"mtllib {material[0]}")
    if colors is not None:
        rgb = _colors_to_uint8(colors).astype(np.float64) / 255.0
        _check_rows("colors", rgb, len(vertices))
        lines += [f"v {x:.6f} {y:.6f} {z:.6f} {r:.4f} {g:.4f} {b:.4f}"
                  for (x, y, z), (r, g, b) in zip(vertices, rgb)]
    else:
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    if uvs is not None:
        uvs = np.asarray(uvs, dtype=np.float64).reshape(-1, 2)
        _check_rows("uvs", uvs, len(vertices))
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in uvs]
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        _check_rows("normals", normals, len(vertices))
        lines += [f"vn {x:.5f} {y:.5f} {z:.5f}" for x, y, z in normals]
    if material is not None:
        lines.append(f"usemtl {material[1]}")
    # Every vertex has its own uv and normal, so one index serves all three (OBJ's v/vt/vn).
    corner = {(True, True): "{0}/{0}/{0}", (True, False): "{0}/{0}", (False, True): "{0}//{0}",
              (False, False): "{0}"}[(uvs is not None, normals is not None)]
    template = " ".join([corner.replace("0", str(k)) for k in range(3)])
    lines += ["f " + template.format(a, b, c) for a, b, c in faces + 1]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def _colors_to_uint8(colors: np.ndarray) -> np.ndarray:
    colors = np.asarray(colors)
    colors = colors.reshape(-1, colors.shape[-1])[:, :3]
    if colors.dtype == np.uint8:
        return colors
    return np.clip(np.round(colors.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)


def _checked_attributes(attributes: dict[str, np.ndarray], n_vertices: int) -> dict[str, np.ndarray]:
    """name -> (V,) float32, after checking each name is a PLY word that means nothing else."""
    checked = {}
    for name, values in attributes.items():
        if not name or not all(c.isalnum() or c == "_" for c in name) or name in _RESERVED_NAMES:
            raise ValueError(f"vertex attribute name {name!r} must be letters, digits and '_' and not one of "
                             f"the PLY's own properties ({', '.join(sorted(_RESERVED_NAMES))})")
        values = np.asarray(values, dtype=np.float32).reshape(-1)
        _check_rows(f"attribute {name!r}", values, n_vertices)
        checked[name] = values
    return checked


def _check_rows(name: str, array: np.ndarray, n: int) -> None:
    if len(array) != n:
        raise ValueError(f"{name} has {len(array)} rows but there are {n} vertices")


# ------------------------------------------------------------------------------------------------ read


def read_ply(path: PathLike) -> Mesh:
    """Read a PLY (ascii, binary_little_endian or binary_big_endian) into a `Mesh`.

    Faces may be any polygons (fan-triangulated); a point cloud gives faces of shape (0, 3).
    Colours are found as red/green/blue (or r/g/b, diffuse_*) and scaled to 0..1 when integer; every
    other scalar vertex property becomes a float32 attribute of that name.
    """
    path = Path(path)
    with open(path, "rb") as f:
        fmt, elements = _read_header(f, path)
        if fmt == "ascii":
            tokens = f.read().split()
            data = _read_ascii(tokens, elements, path)
        else:
            order = "<" if fmt == "binary_little_endian" else ">"
            data = _read_binary(f, elements, order, path)

    vertex = data.get("vertex")
    if vertex is None:
        raise ValueError(f"{path}: no 'vertex' element")
    vertices = np.stack([vertex[k] for k in _POSITION_NAMES], axis=1).astype(np.float32)
    normals = None
    if all(k in vertex for k in _NORMAL_NAMES):
        normals = np.stack([vertex[k] for k in _NORMAL_NAMES], axis=1).astype(np.float32)
    colors = None
    for names in _COLOUR_NAMES:
        if all(k in vertex for k in names):
            raw = np.stack([vertex[k] for k in names], axis=1)
            colors = raw.astype(np.float32) / (255.0 if np.issubdtype(raw.dtype, np.integer) else 1.0)
            break
    faces = data.get("face", {}).get("vertex_indices", data.get("face", {}).get("vertex_index"))
    faces = np.zeros((0, 3), np.int32) if faces is None else faces
    attributes = {name: np.asarray(values, dtype=np.float32) for name, values in vertex.items()
                  if name not in _RESERVED_NAMES and np.ndim(values) == 1}
    return Mesh(vertices, faces, normals, colors, attributes)


def _read_header(f: BinaryIO, path: Path) -> tuple[str, list[_Element]]:
    if f.readline().strip() != b"ply":
        raise ValueError(f"{path}: not a PLY file (first line is not 'ply')")
    fmt = ""
    elements: list[_Element] = []
    while True:
        line = f.readline()
        if not line:
            raise ValueError(f"{path}: PLY header has no end_header")
        words = line.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format":
            fmt = words[1]
            if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise ValueError(f"{path}: unknown PLY format {fmt!r}")
        elif words[0] == "element":
            elements.append(_Element(words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise ValueError(f"{path}: property before any element")
            if words[1] == "list":
                elements[-1].properties.append(_Property(words[4], _PLY_TYPES[words[3]], _PLY_TYPES[words[2]]))
            else:
                elements[-1].properties.append(_Property(words[2], _PLY_TYPES[words[1]]))
    return fmt, elements


def _read_binary(f: BinaryIO, elements: list[_Element], order: str, path: Path) -> dict[str, dict[str, np.ndarray]]:
    data: dict[str, dict[str, np.ndarray]] = {}
    for element in elements:
        lists = [p for p in element.properties if p.count_dtype is not None]
        if not lists:
            dtype = np.dtype([(p.name, order + p.dtype) for p in element.properties])
            raw = np.frombuffer(f.read(dtype.itemsize * element.count), dtype=dtype, count=element.count)
            data[element.name] = {p.name: raw[p.name] for p in element.properties}
            continue
        if element.name == "face" and len(element.properties) == 1:
            data[element.name] = {lists[0].name: _read_binary_faces(f, element, lists[0], order, path)}
            continue
        # A mixed element with lists (rare: e.g. faces with extra properties): slow generic parse.
        data[element.name] = _read_binary_generic(f, element, order)
    return data


def _read_binary_faces(f: BinaryIO, element: _Element, prop: _Property, order: str, path: Path) -> np.ndarray:
    """Faces stored as one list property. Fast path when every polygon has the same corner count."""
    count_dtype = np.dtype(order + prop.count_dtype)
    index_dtype = np.dtype(order + prop.dtype)
    start = f.tell()
    if element.count == 0:
        return np.zeros((0, 3), np.int32)
    first = int(np.frombuffer(f.read(count_dtype.itemsize), dtype=count_dtype)[0])
    f.seek(start)
    fixed = np.dtype([("n", count_dtype), ("v", index_dtype, (first,))])
    buffer = f.read(fixed.itemsize * element.count)
    if len(buffer) == fixed.itemsize * element.count:
        raw = np.frombuffer(buffer, dtype=fixed)
        if np.all(raw["n"] == first):
            return _triangulate([raw["v"].astype(np.int64)])
    # Mixed polygon sizes: walk the records one by one.
    f.seek(start)
    polygons = []
    for _ in range(element.count):
        n = int(np.frombuffer(f.read(count_dtype.itemsize), dtype=count_dtype)[0])
        polygons.append(np.frombuffer(f.read(index_dtype.itemsize * n), dtype=index_dtype).astype(np.int64))
    if not polygons:
        raise ValueError(f"{path}: empty face element")
    return _triangulate_ragged(polygons)


def _read_binary_generic(f: BinaryIO, element: _Element, order: str) -> dict[str, np.ndarray]:
    columns: dict[str, list] = {p.name: [] for p in element.properties}
    for _ in range(element.count):
        for p in element.properties:
            if p.count_dtype is None:
                dt = np.dtype(order + p.dtype)
                columns[p.name].append(np.frombuffer(f.read(dt.itemsize), dtype=dt)[0])
            else:
                cdt, idt = np.dtype(order + p.count_dtype), np.dtype(order + p.dtype)
                n = int(np.frombuffer(f.read(cdt.itemsize), dtype=cdt)[0])
                columns[p.name].append(np.frombuffer(f.read(idt.itemsize * n), dtype=idt).astype(np.int64))
    out: dict[str, np.ndarray] = {}
    for p in element.properties:
        out[p.name] = _triangulate_ragged(columns[p.name]) if p.count_dtype else np.array(columns[p.name])
    return out


def _read_ascii(tokens: list[bytes], elements: list[_Element], path: Path) -> dict[str, dict[str, np.ndarray]]:
    data: dict[str, dict[str, np.ndarray]] = {}
    pos = 0
    for element in elements:
        props = element.properties
        if all(p.count_dtype is None for p in props):
            n = len(props) * element.count
            table = np.array(tokens[pos:pos + n], dtype=np.float64).reshape(element.count, len(props))
            pos += n
            data[element.name] = {p.name: table[:, i].astype(p.dtype) for i, p in enumerate(props)}
            continue
        columns: dict[str, list] = {p.name: [] for p in props}
        for _ in range(element.count):
            for p in props:
                if p.count_dtype is None:
                    columns[p.name].append(float(tokens[pos]))
                    pos += 1
                else:
                    n = int(tokens[pos])
                    columns[p.name].append(np.array(tokens[pos + 1:pos + 1 + n], dtype=np.int64))
                    pos += 1 + n
        data[element.name] = {
            p.name: _triangulate_ragged(columns[p.name]) if p.count_dtype else np.array(columns[p.name], dtype=p.dtype)
            for p in props
        }
    if pos > len(tokens):
        raise ValueError(f"{path}: ascii PLY body is shorter than its header says")
    return data


def _triangulate(blocks: list[np.ndarray]) -> np.ndarray:
    """Fan-triangulate equal-size polygons: blocks of (N, k) indices -> (N*(k-2), 3) int32."""
    out = []
    for polys in blocks:
        k = polys.shape[1]
        if k < 3:
            continue
        fans = [np.stack([polys[:, 0], polys[:, i], polys[:, i + 1]], axis=1) for i in range(1, k - 1)]
        # Keep the fans of one polygon together so triangle order follows polygon order.
        out.append(np.stack(fans, axis=1).reshape(-1, 3))
    return np.concatenate(out).astype(np.int32) if out else np.zeros((0, 3), np.int32)


def _triangulate_ragged(polygons: list[np.ndarray]) -> np.ndarray:
    by_size: dict[int, list[int]] = {}
    for i, poly in enumerate(polygons):
        by_size.setdefault(len(poly), []).append(i)
    if len(by_size) == 1:
        return _triangulate([np.stack(polygons)])
    tris = [_triangulate([poly[None]]) for poly in polygons]
    return np.concatenate(tris) if tris else np.zeros((0, 3), np.int32)
