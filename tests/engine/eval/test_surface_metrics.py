"""Surface metrics (engine/eval/surface_metrics.py): hand-computable meshes, a noisy room, the eval CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from engine.__main__ import main as engine_main
from engine.eval.surface_metrics import evaluate_surface
from engine.mesh_io import Mesh, write_ply
from engine.meshops import merge_duplicate_vertices
from engine.tsdf import TsdfVolume


def grid_rectangle(origin, u, v, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The parallelogram origin + [0, 1] u + [0, 1] v as a grid of right triangles about `step` apart."""
    origin, u, v = (np.asarray(x, np.float64) for x in (origin, u, v))
    nu, nv = (max(1, int(round(np.linalg.norm(e) / step))) for e in (u, v))
    i, j = np.meshgrid(np.arange(nu + 1) / nu, np.arange(nv + 1) / nv, indexing="ij")
    points = origin + i.reshape(-1, 1) * u + j.reshape(-1, 1) * v
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
    return points, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def joined(parts: list[tuple[np.ndarray, np.ndarray]], weld: bool = True) -> Mesh:
    vertices, faces, start = [], [], 0
    for v, f in parts:
        vertices.append(v)
        faces.append(f + start)
        start += len(v)
    v, f = np.concatenate(vertices), np.concatenate(faces)
    if weld:
        v, f = merge_duplicate_vertices(v, f)
    return Mesh(v.astype(np.float32), f.astype(np.int32))


def square(size: float = 1.0, offset=(0.0, 0.0, 0.0), step: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    return grid_rectangle(offset, [size, 0, 0], [0, size, 0], step or size)


def box_sides(lo, hi, step: float) -> list[tuple[np.ndarray, np.ndarray]]:
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    ex, ey, ez = np.diag(hi - lo)
    return [grid_rectangle(o, u, v, step) for o, u, v in
            ((lo, ex, ey), (lo + ez, ex, ey), (lo, ex, ez), (lo + ey, ex, ez), (lo, ey, ez), (lo + ex, ey, ez))]


def test_unit_square_against_itself():
    m = evaluate_surface(joined([square()]), joined([square()]))
    assert m.pieces == 1 and m.floater_share == 0
    assert m.area == pytest.approx(1.0) and m.gt_area == pytest.approx(1.0) and m.area_ratio == pytest.approx(1.0)
    assert m.boundary_per_m2 == pytest.approx(4.0)  # the square's 4 m of open edge over 1 m^2
    assert m.normal_agreement == 1.0


def test_pieces_count_the_surface_not_its_vertex_copies():
    # The square as two triangles with their own copies of the shared diagonal (as a per-triangle export writes it).
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    split = Mesh(v, np.array([[0, 1, 2], [3, 4, 5]], np.int32))
    m = evaluate_surface(split, joined([square()]))
    assert m.pieces == 1 and m.boundary_per_m2 == pytest.approx(4.0)  # the diagonal is not open

    two = evaluate_surface(joined([square(), square(offset=(2, 0, 0))]), joined([square()]))
    assert two.pieces == 2 and two.boundary_per_m2 == pytest.approx(8.0 / 2.0)
    assert two.area_ratio == pytest.approx(2.0)  # no trimming: the second square is extra surface


def test_a_tiny_floater_is_its_share_of_the_area():
    m = evaluate_surface(joined([square(), square(0.1, offset=(0.2, 0.2, 1.0))]), joined([square()]))
    assert m.pieces == 2
    assert m.floater_share == pytest.approx(0.01 / 1.01)
    # A 0.5 m square (0.25 m^2) is not under the floater size: no floater.
    assert evaluate_surface(joined([square(), square(0.5, offset=(0, 0, 1))]), joined([square()])).floater_share == 0


def test_a_closed_box_has_no_open_boundary():
    closed = evaluate_surface(joined(box_sides([0, 0, 0], [1, 1, 1], 0.25)), joined([square()]))
    assert closed.pieces == 1 and closed.boundary_per_m2 == 0
    open_top = evaluate_surface(joined(box_sides([0, 0, 0], [1, 1, 1], 0.25)[:1] + box_sides([0, 0, 0], [1, 1, 1], 0.25)[2:]),
                                joined([square()]))
    assert open_top.boundary_per_m2 == pytest.approx(4.0 / 5.0)  # the missing lid's 4 m rim over 5 m^2


def rotated_about_x(mesh: Mesh, degrees: float, centre_y: float) -> Mesh:
    a = np.radians(degrees)
    rotation = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    v = (mesh.vertices - [0, centre_y, 0]) @ rotation.T + [0, centre_y, 0]
    return Mesh(v.astype(np.float32), mesh.faces)


def test_normal_agreement_is_an_unoriented_30_degree_test_near_the_truth():
    truth = joined([square(2.0, step=0.1)])
    flipped = Mesh(truth.vertices, truth.faces[:, ::-1].copy())
    assert evaluate_surface(flipped, truth).normal_agreement == 1.0  # winding is not shape
    # A plane tilted through the truth's middle: only the strip within 5 cm of the truth is judged.
    assert evaluate_surface(rotated_about_x(truth, 20, 1.0), truth).normal_agreement == 1.0
    assert evaluate_surface(rotated_about_x(truth, 40, 1.0), truth).normal_agreement == 0.0
    far = evaluate_surface(Mesh(truth.vertices + np.float32([0, 0, 0.2]), truth.faces), truth)
    assert far.normal_agreement == 0.0 and far.area_ratio == pytest.approx(1.0)  # nothing within 5 cm


def test_area_ratio_is_trimmed_to_observed_space_like_the_f_score():
    weight = np.zeros((10, 10, 10), np.float32)
    weight[:5] = 1  # only x < 0.2 m observed (voxel corners at 0, 0.04, ... 0.16)
    observed = TsdfVolume(np.ones_like(weight), weight, np.zeros(3), 0.04, 0.12)
    truth = joined([square(0.16, offset=(0, 0, 0.1), step=0.04)])
    pred = joined([square(0.16, offset=(0, 0, 0.1), step=0.04), square(0.16, offset=(0.25, 0, 0.1), step=0.04)])
    assert evaluate_surface(pred, truth).area_ratio == pytest.approx(2.0)
    trimmed = evaluate_surface(pred, truth, observed=observed)
    assert trimmed.area_ratio == pytest.approx(1.0, abs=0.01) and trimmed.area == pytest.approx(0.16**2, rel=0.02)
    assert trimmed.pieces == 2  # pieces, floaters and boundary describe the whole mesh the user gets


def test_an_empty_prediction_has_no_surface():
    m = evaluate_surface(Mesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)), joined([square()]))
    assert (m.pieces, m.area, m.area_ratio, m.normal_agreement, m.floater_share, m.boundary_per_m2) == (0, 0, 0, 0, 0, 0)


def test_vertex_noise_on_a_room_lowers_normal_agreement_as_on_a_real_kitchen():
    # A 2.4 x 2.0 x 2.2 m room with a table, tessellated at 3 cm (edges 3 and 4.2 cm, as marching cubes
    # at 4 cm voxels gives), against the same mesh with Gaussian noise on every vertex. On a real kitchen
    # the expected shape was 0.87 / 0.57 / 0.27 at 5 mm / 1 cm / 2 cm; this room gives 0.90 / 0.52 / 0.25.
    truth = joined(box_sides([0, 0, 0], [2.4, 2.0, 2.2], 0.03) + box_sides([0.6, 0.5, 0.0], [1.4, 1.1, 0.75], 0.03))
    rng = np.random.default_rng(1)
    scores = {}
    for sigma in (0.005, 0.01, 0.02):
        noisy = Mesh(truth.vertices + rng.normal(0, sigma, truth.vertices.shape).astype(np.float32), truth.faces)
        scores[sigma] = evaluate_surface(noisy, truth)
    agreement = [scores[s].normal_agreement for s in (0.005, 0.01, 0.02)]
    assert agreement[0] > agreement[1] > agreement[2]
    assert 0.8 < agreement[0] < 0.95 and 0.42 < agreement[1] < 0.65 and 0.15 < agreement[2] < 0.35, agreement
    # Crumpling adds area; the noise neither tears the mesh nor makes floaters.
    assert 1.0 < scores[0.005].area_ratio < scores[0.01].area_ratio < scores[0.02].area_ratio
    assert all(m.floater_share == 0 and m.boundary_per_m2 == 0 for m in scores.values())


def test_eval_cli_prints_and_writes_the_surface_metrics(tmp_path, capsys):
    truth = joined([square(2.0, step=0.05)])
    pred = joined([square(2.0, step=0.05), square(0.2, offset=(0.5, 0.5, 1.0), step=0.05)])
    write_ply(tmp_path / "gt.ply", truth.vertices, truth.faces)
    write_ply(tmp_path / "pred.ply", pred.vertices, pred.faces)
    out = tmp_path / "metrics.json"
    assert engine_main(["eval", str(tmp_path / "pred.ply"), str(tmp_path / "gt.ply"), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    for heading in ("normals", "floaters", "pieces", "area ratio", "boundary m/m2"):
        assert heading in printed
    surface = json.loads(out.read_text())["surface"]["pred.ply"]
    assert surface["pieces"] == 2 and surface["floater_share"] == pytest.approx(0.04 / 4.04)
    assert surface["area_ratio"] == pytest.approx(4.04 / 4.0) and surface["normal_agreement"] == 1.0
