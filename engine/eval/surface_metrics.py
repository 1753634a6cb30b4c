"""Surface quality of a predicted mesh against the truth, beside the Atlas F-score (mesh_metrics.py).

The F-score asks whether surface points lie within 5 cm of the truth. It cannot see what a user
notices when looking at the mesh: crumpled facets that shade like crushed foil although they lie in
the right place, dust of small floating pieces, holes and ragged edges, surface that is missing or
doubled. These numbers measure that, for any mesh and truth:

- normal agreement: of the predicted surface within `threshold` (5 cm) of the truth, the share (by
  area) whose face normal is within 30 degrees of the normal of the nearest truth sample. The angle
  is unoriented (|cos|): marching cubes orients its faces by the TSDF sign, a modelled or scanned
  truth by whatever winding its author used, and a flipped face still lies where the truth does; so
  this measures the shape of the surface, not its winding. 1 for a perfect surface.
- floater share: the share of the predicted area in connected pieces smaller than 0.25 m^2 (dust in
  the air, fragments seen by one photo). 0 is best.
- pieces: connected pieces (triangles sharing a vertex) after merging duplicate vertices, so tiled or
  per-triangle exports count as the surface they are.
- area ratio: predicted area / true area, both trimmed to observed space exactly as the F-score
  trims its points (trim.py); < 1 is missing surface, > 1 doubled or extra surface.
- boundary per m^2: the length of open edges (used by exactly one face) per m^2 of predicted area,
  in 1/m; holes and ragged borders raise it, a closed surface has 0.

Normal agreement and area ratio compare with the truth and so are trimmed like the F-score; pieces,
floaters and boundary describe the predicted mesh as the user gets it and are taken on all of it.

Both meshes are judged by area-uniform samples, about one per `spacing`^2 of surface (every face gets
ceil(area / spacing^2), each sample weighted by its share of the face's area, so sums of weights are
exact areas), carrying their face's normal. A fixed random seed makes the numbers repeatable.
Everything is vectorised numpy + scipy (cKDTree, connected components): a million faces take seconds.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Optional

import numpy as np
from scipy.spatial import cKDTree

from ..mesh_io import Mesh
from ..meshops import face_pieces, merge_duplicate_vertices
from ..tsdf.volume import TsdfVolume
from .trim import observed_mask

NORMAL_ANGLE_DEG = 30.0
FLOATER_AREA = 0.25  # m^2: a piece smaller than a 50 x 50 cm sheet is dust, not part of the room
SAMPLE_SPACING = 0.02  # m: samples per m^2 = 1 / spacing^2; at least one per 4 cm marching-cubes facet
WELD_TOLERANCE = 1e-6  # m: vertices closer than this are the same vertex
SAMPLE_SEED = 0

# (key, column heading, format): the one order and spelling every entry point prints.
SURFACE_COLUMNS = (
    ("normal_agreement", "normals", "{:.3f}"),
    ("floater_share", "floaters", "{:.3f}"),
    ("pieces", "pieces", "{}"),
    ("area_ratio", "area ratio", "{:.3f}"),
    ("boundary_per_m2", "boundary m/m2", "{:.2f}"),
)
SURFACE_KEYS = tuple(key for key, _, _ in SURFACE_COLUMNS)
SURFACE_LEGEND = (f"normals = share of the surface within the threshold of the truth whose normal is within "
                  f"{NORMAL_ANGLE_DEG:g} deg of the truth's; floaters = share of the area in pieces under "
                  f"{FLOATER_AREA:g} m2; area ratio = area / true area, trimmed like F; boundary = open-edge "
                  "length per m2")


@dataclass
class SurfaceMetrics:
    normal_agreement: float  # 0..1, share of near-truth predicted area with normals within 30 deg
    floater_share: float  # 0..1, share of predicted area in pieces under 0.25 m^2
    pieces: int  # connected pieces of the predicted mesh
    area_ratio: float  # trimmed predicted area / trimmed true area
    boundary_per_m2: float  # open-edge length (m) per m^2 of predicted area
    area: float  # m^2, predicted, trimmed as the F-score trims
    gt_area: float  # m^2, truth, trimmed as the F-score trims

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class SurfaceSamples:
    """points (S, 3) and unit face normals (S, 3) float64; weights (S,) m^2 of surface per sample."""

    points: np.ndarray
    normals: np.ndarray
    weights: np.ndarray


@dataclass
class MeshTopology:
    """pieces; area (m^2) of the whole mesh and of its pieces under FLOATER_AREA; open-edge length (m)."""

    pieces: int
    area: float
    floater_area: float
    boundary_length: float


def clean_faces(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, faces (F, 3) int64) with duplicate vertices merged and the faces
    touching non-finite vertices (marching cubes on a NaN-masked volume leaves some) dropped."""
    vertices = np.asarray(mesh.vertices, np.float64).reshape(-1, 3)
    faces = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        faces = (np.cumsum(finite) - 1)[faces[finite[faces].all(axis=1)]]
        vertices = vertices[finite]
    return merge_duplicate_vertices(vertices, faces, WELD_TOLERANCE)


def face_areas_and_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F,) areas in m^2 and (F, 3) unit normals (zero for degenerate faces)."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    cross = np.cross(b - a, c - a)
    length = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, length[:, None], out=np.zeros_like(cross), where=length[:, None] > 0)
    return 0.5 * length, normals


def sample_surface(vertices: np.ndarray, faces: np.ndarray, spacing: float = SAMPLE_SPACING,
                   seed: int = SAMPLE_SEED) -> SurfaceSamples:
    """Area-uniform samples of a triangle mesh with their face normals (see the module docstring)."""
    areas, normals = face_areas_and_normals(vertices, faces)
    counts = np.ceil(areas / spacing**2).astype(np.int64)  # 0 only for zero-area faces
    face = np.repeat(np.arange(len(faces)), counts)
    rng = np.random.default_rng(seed)
    r1, r2 = np.sqrt(rng.random(len(face))), rng.random(len(face))
    # Uniform in a triangle: a + sqrt(r1) (1 - r2) (b - a) + sqrt(r1) r2 (c - a).
    a, b, c = (vertices[faces[face, k]] for k in range(3))
    points = a + (r1 * (1 - r2))[:, None] * (b - a) + (r1 * r2)[:, None] * (c - a)
    weights = (areas / np.maximum(counts, 1))[face]
    return SurfaceSamples(points, normals[face], weights)


def mesh_topology(vertices: np.ndarray, faces: np.ndarray, floater_area: float = FLOATER_AREA) -> MeshTopology:
    """Pieces, areas and open boundary of a mesh whose duplicate vertices are already merged."""
    if len(faces) == 0:
        return MeshTopology(0, 0.0, 0.0, 0.0)
    areas, _ = face_areas_and_normals(vertices, faces)
    labels, _ = face_pieces(faces, len(vertices))
    piece_areas = np.bincount(labels, weights=areas)
    small = piece_areas < floater_area
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    keys, uses = np.unique(edges[:, 0] * len(vertices) + edges[:, 1], return_counts=True)
    open_edges = keys[uses == 1]
    ends = np.stack([open_edges // len(vertices), open_edges % len(vertices)], axis=1)
    boundary = np.linalg.norm(vertices[ends[:, 0]] - vertices[ends[:, 1]], axis=1).sum()
    return MeshTopology(len(piece_areas), float(areas.sum()), float(piece_areas[small].sum()), float(boundary))


def evaluate_surface(
    pred: Mesh,
    gt: Mesh,
    observed: Optional[TsdfVolume] = None,
    threshold: float = 0.05,
    trim_gt: bool = True,
    spacing: float = SAMPLE_SPACING,
    normal_angle_deg: float = NORMAL_ANGLE_DEG,
    floater_area: float = FLOATER_AREA,
) -> SurfaceMetrics:
    """The surface metrics of `pred` against `gt`, both in world metres.

    observed and trim_gt as in `evaluate_mesh`: the ground-truth TSDF whose observed voxels both
    meshes' samples are trimmed to (the truth only when trim_gt). A prediction without faces (a point
    cloud or an empty result) has no surface: every share and ratio is 0 and it has 0 pieces; a truth
    with no surface left after trimming gives an infinite area ratio (as `point_metrics` gives
    infinite distances against an empty side).
    """
    pred_vertices, pred_faces = clean_faces(pred)
    topology = mesh_topology(pred_vertices, pred_faces, floater_area)
    pred_samples = sample_surface(pred_vertices, pred_faces, spacing)
    gt_samples = sample_surface(*clean_faces(gt), spacing)
    if observed is not None:
        pred_samples = _subset(pred_samples, observed_mask(pred_samples.points, observed))
        if trim_gt:
            gt_samples = _subset(gt_samples, observed_mask(gt_samples.points, observed))
    area, gt_area = float(pred_samples.weights.sum()), float(gt_samples.weights.sum())
    agreement = 0.0
    if len(pred_samples.points) and len(gt_samples.points):
        distance, nearest = cKDTree(gt_samples.points).query(pred_samples.points, k=1,
                                                             distance_upper_bound=threshold)
        near = distance < threshold
        cosine = np.abs(np.einsum("ij,ij->i", pred_samples.normals[near], gt_samples.normals[nearest[near]]))
        agrees = cosine >= np.cos(np.radians(normal_angle_deg))
        near_area = pred_samples.weights[near].sum()
        agreement = float(pred_samples.weights[near][agrees].sum() / near_area) if near_area > 0 else 0.0
    return SurfaceMetrics(
        normal_agreement=agreement,
        floater_share=topology.floater_area / topology.area if topology.area > 0 else 0.0,
        pieces=topology.pieces,
        area_ratio=area / gt_area if gt_area > 0 else float("inf"),
        boundary_per_m2=topology.boundary_length / topology.area if topology.area > 0 else 0.0,
        area=area,
        gt_area=gt_area,
    )


def _subset(samples: SurfaceSamples, keep: np.ndarray) -> SurfaceSamples:
    return SurfaceSamples(samples.points[keep], samples.normals[keep], samples.weights[keep])


def surface_cells(metrics: SurfaceMetrics | dict) -> list[str]:
    """The SURFACE_COLUMNS values of one result as printed strings; a dict is `SurfaceMetrics.as_dict()`
    or a mean of several (whose piece count may be fractional: printed with one decimal)."""
    values = metrics.as_dict() if isinstance(metrics, SurfaceMetrics) else metrics
    cells = []
    for key, _, fmt in SURFACE_COLUMNS:
        value = values[key]
        if key == "pieces":
            cells.append(f"{int(value)}" if float(value).is_integer() else f"{value:.1f}")
        else:
            cells.append(fmt.format(value))
    return cells


def surface_table(rows: dict[str, SurfaceMetrics | dict], indent: str = "") -> str:
    """A plain-text table, one row per name, the SURFACE_COLUMNS in their order."""
    width = max(len(name) for name in rows) + 2
    widths = [max(len(heading), 8) + 2 for _, heading, _ in SURFACE_COLUMNS]
    lines = [indent + "".ljust(width) + "".join(h.rjust(w) for (_, h, _), w in zip(SURFACE_COLUMNS, widths))]
    for name, metrics in rows.items():
        lines.append(indent + name.ljust(width) + "".join(c.rjust(w) for c, w in zip(surface_cells(metrics), widths)))
    return "\n".join(lines)


def surface_headings() -> list[str]:
    """The SURFACE_COLUMNS' headings, in their order (tables and one-line summaries)."""
    return [heading for _, heading, _ in SURFACE_COLUMNS]
