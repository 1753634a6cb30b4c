"""Atlas metrics, depth metrics, trimming and the room-box baseline against hand-computed numbers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from engine.__main__ import main as engine_main
from engine.eval import (
    box_mesh,
    depth_metrics,
    evaluate_mesh,
    fit_room_box,
    mean_depth_metrics,
    observed_mask,
    point_metrics,
    surface_points,
    voxel_down_sample,
)
from engine.mesh_io import Mesh, write_ply
from engine.tsdf import TsdfVolume

GRID = np.array([[x, y, 0.0] for x in range(3) for y in range(3)])  # 9 points 1 m apart


def test_point_metrics_hand_computed():
    perfect = point_metrics(GRID, GRID)
    assert (perfect.acc, perfect.comp, perfect.prec, perfect.recall, perfect.fscore) == (0, 0, 1, 1, 1)

    near = point_metrics(GRID + [0, 0, 0.03], GRID)  # every point 3 cm off: inside the 5 cm threshold
    assert near.acc == pytest.approx(0.03) and near.comp == pytest.approx(0.03)
    assert (near.prec, near.recall, near.fscore) == (1, 1, 1)

    far = point_metrics(GRID + [0, 0, 0.10], GRID)  # 10 cm off: outside it
    assert far.acc == pytest.approx(0.10) and (far.prec, far.recall, far.fscore) == (0, 0, 0)

    # Prediction = the 9 points 3 cm off plus 9 outliers 0.5 m above: half the prediction is right,
    # all of the ground truth is found. P = 0.5, R = 1, F = 2 * 0.5 / 1.5.
    pred = np.concatenate([GRID + [0, 0, 0.03], GRID + [0, 0, 0.5]])
    mixed = point_metrics(pred, GRID)
    assert mixed.prec == 0.5 and mixed.recall == 1 and mixed.fscore == pytest.approx(2 / 3)
    assert mixed.acc == pytest.approx((0.03 + 0.5) / 2) and mixed.comp == pytest.approx(0.03)
    assert point_metrics(np.zeros((0, 3)), GRID).fscore == 0


def plane(z: float, size: float = 1.0) -> Mesh:
    v = np.array([[0, 0, z], [size, 0, z], [size, size, z], [0, size, z]], np.float32)
    return Mesh(v, np.array([[0, 1, 2], [0, 2, 3]], np.int32))


def test_mesh_metrics_on_shifted_planes():
    # Two big triangles: metrics need surface samples, not the 4 corner vertices.
    same = evaluate_mesh(plane(0), plane(0))
    assert same.fscore == 1 and same.acc < 1e-9 and same.n_pred == same.n_gt == 51 * 51  # cells start half a voxel below the min
    shifted = evaluate_mesh(plane(0.03), plane(0))
    assert shifted.acc == pytest.approx(0.03, abs=1e-6) and shifted.fscore == 1
    assert evaluate_mesh(plane(0.10), plane(0)).fscore == 0


def test_voxel_down_sample_follows_open3d_anchor():
    pts = np.array([[0.0, 0, 0], [0.005, 0, 0], [0.015, 0, 0]])
    # Cells start at min - voxel/2 = -0.01: [-0.01, 0.01) holds 0 and 0.005; [0.01, 0.03) holds 0.015.
    out = voxel_down_sample(pts, 0.02)
    np.testing.assert_allclose(sorted(out[:, 0]), [0.0025, 0.015])


def test_surface_points_cover_a_large_triangle():
    v = np.array([[0, 0, 0], [3, 0, 0], [0, 2, 0]], float)
    pts = surface_points(v, np.array([[0, 1, 2]]), spacing=0.01, down_sample=0.02)
    probe = np.random.default_rng(1).random((2000, 2)) * [3, 2]
    probe = probe[probe[:, 0] / 3 + probe[:, 1] / 2 < 1]
    from scipy.spatial import cKDTree

    d = cKDTree(pts[:, :2]).query(probe)[0]
    assert d.max() < 0.02 and np.all(np.abs(pts[:, 2]) < 1e-12)


def test_trimming_to_observed_voxels():
    weight = np.zeros((10, 10, 10), np.float32)
    weight[:5] = 1  # only x < 0.2 m observed (voxel corners at 0, 0.04, ... 0.16)
    vol = TsdfVolume(np.ones_like(weight), weight, np.zeros(3), 0.04, 0.12)
    pts = np.array([[0.05, 0.1, 0.1], [0.17, 0.1, 0.1], [0.19, 0.1, 0.1], [0.3, 0.1, 0.1], [-0.5, 0, 0]])
    assert observed_mask(pts, vol).tolist() == [True, True, False, False, False]
    # A prediction with a wall in unobserved space is not penalised once trimmed.
    pred = Mesh(np.concatenate([plane(0.1, 0.16).vertices, plane(0.1, 0.16).vertices + [0.25, 0, 0]]),
                np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], np.int32))
    gt = plane(0.1, 0.16)
    assert evaluate_mesh(pred, gt).prec < 0.6
    assert evaluate_mesh(pred, gt, observed=vol).prec == 1


@pytest.mark.parametrize("tsdf_name", ["tsdf_gt.npz", "tsdf_gt_04.npz"])
def test_eval_cli_on_a_room_folder_trims_with_its_ground_truth_tsdf(tmp_path, capsys, tsdf_name):
    # tsdf_gt.npz comes from the renderer, tsdf_gt_04.npz from training's fusion (rooms rendered with --no-tsdf).
    room = tmp_path / "room"
    room.mkdir()
    weight = np.zeros((10, 10, 10), np.float32)
    weight[:5] = 1  # only x < 0.2 m observed
    TsdfVolume(np.ones_like(weight), weight, np.zeros(3), 0.04, 0.12).save(room / tsdf_name)
    gt = plane(0.1, 0.16)
    write_ply(room / "mesh_gt.ply", gt.vertices, gt.faces)
    pred = Mesh(np.concatenate([gt.vertices, gt.vertices + [0.25, 0, 0]]), np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], np.int32))
    write_ply(tmp_path / "pred.ply", pred.vertices, pred.faces)
    assert engine_main(["eval", str(tmp_path / "pred.ply"), str(room), "--json", str(tmp_path / "m.json")]) == 0
    assert "trimmed to observed voxels: prediction and ground truth" in capsys.readouterr().out
    result = json.loads((tmp_path / "m.json").read_text())
    assert result["observed"] == str(room / tsdf_name) and result["results"]["pred.ply"]["prec"] == 1


def test_depth_metrics_hand_computed():
    pred = np.array([[1.0, 2.0], [0.0, 4.0]])
    true = np.array([[1.0, 1.0], [2.0, 5.0]])
    m = depth_metrics(pred, true)  # compared pixels: (1,1), (2,1), (4,5)
    assert m["AbsRel"] == pytest.approx((0 + 1 + 0.2) / 3)
    assert m["AbsDiff"] == pytest.approx(2 / 3)
    assert m["SqRel"] == pytest.approx((0 + 1 + 1 / 5) / 3)
    assert m["RMSE"] == pytest.approx(np.sqrt(2 / 3))
    assert m["LogRMSE"] == pytest.approx(np.sqrt((np.log(2) ** 2 + np.log(0.8) ** 2) / 3))
    assert (m["r1"], m["r2"], m["r3"]) == pytest.approx((1 / 3, 2 / 3, 2 / 3))
    assert m["complete"] == 0.75
    avg = mean_depth_metrics([m, depth_metrics(true, true)])
    assert avg["AbsDiff"] == pytest.approx(1 / 3) and avg["r1"] == pytest.approx(2 / 3)


def test_room_box_baseline():
    box = box_mesh([0, 0, 0], [4, 3, 2.5])
    v = box.vertices.astype(float)
    n = np.cross(v[box.faces[:, 1]] - v[box.faces[:, 0]], v[box.faces[:, 2]] - v[box.faces[:, 0]])
    to_centre = np.array([2, 1.5, 1.25]) - v[box.faces].mean(axis=1)
    assert len(box.faces) == 12 and np.all(np.einsum("ij,ij->i", n, to_centre) > 0)  # normals face inward
    # Points on the six sides, a table top, a patch seen through a window 2 m outside the room, and a
    # stray: the box sits on the dominant planes, not on the extent.
    rng = np.random.default_rng(0)
    sides = []
    for axis in range(3):
        for value in (0.0, [4, 3, 2.5][axis]):
            p = rng.random((3000, 3)) * [4, 3, 2.5]
            p[:, axis] = value
            sides.append(p)
    table = np.c_[rng.uniform(1, 2, (800, 2)), np.full(800, 0.75)]
    outside = np.c_[np.full(600, -2.0), rng.uniform(1, 2, 600), rng.uniform(1, 2, 600)]
    fitted = fit_room_box(np.concatenate(sides + [table, outside, [[40.0, 40, 40]]]))
    np.testing.assert_allclose(fitted.vertices.min(0), [0, 0, 0], atol=0.03)
    np.testing.assert_allclose(fitted.vertices.max(0), [4, 3, 2.5], atol=0.03)
    assert evaluate_mesh(box, box).fscore == 1


def test_eval_cli_prints_table_and_writes_json(tmp_path, capsys):
    write_ply(tmp_path / "pred.ply", plane(0.03).vertices, plane(0.03).faces)
    write_ply(tmp_path / "gt.ply", plane(0).vertices, plane(0).faces)
    rc = engine_main(["eval", str(tmp_path / "pred.ply"), str(tmp_path / "gt.ply"), "--box-baseline",
                      "--json", str(tmp_path / "m.json")])
    assert rc == 0
    out = capsys.readouterr().out
    assert "fscore" in out and "room box baseline" in out
    result = json.loads((tmp_path / "m.json").read_text())["results"]["pred.ply"]
    assert result["fscore"] == 1 and result["acc"] == pytest.approx(0.03, abs=1e-6)
    assert engine_main(["eval", str(tmp_path / "missing.ply"), str(tmp_path / "gt.ply")]) == 1


def test_nan_vertices_are_ignored():
    # Marching cubes on a NaN-masked TSDF can emit NaN vertices; their faces are dropped.
    good = plane(0)
    v = np.concatenate([good.vertices, [[np.nan, np.nan, np.nan]]]).astype(np.float32)
    f = np.concatenate([good.faces, [[0, 1, 4]]]).astype(np.int32)
    m = evaluate_mesh(Mesh(v, f), good)
    assert m.fscore == 1 and m.n_pred == 51 * 51


def _box_room_views():
    from fixtures_rooms import box_room

    room = box_room(size=(3.0, 2.6, 2.4), n_frames=6, image_size=(64, 48))
    return room, [(K, pose, depth) for K, pose, depth in zip(room.K, room.poses, room.depths)]


def test_mesh_depth_metrics_against_analytic_depth():
    from engine.eval.depth_metrics import mesh_depth_metrics

    _, views = _box_room_views()  # depth by exact ray-box intersection, independent of the rasteriser
    exact = box_mesh([0, 0, 0], [3.0, 2.6, 2.4])
    m = mesh_depth_metrics(exact.vertices, exact.faces, views)
    assert m["complete"] > 0.99 and m["r1"] > 0.99 and m["AbsRel"] < 0.01
    shrunk = box_mesh([0.3, 0.3, 0.3], [2.7, 2.3, 2.1])  # every wall 30 cm closer
    m = mesh_depth_metrics(shrunk.vertices, shrunk.faces, views)
    assert 0.15 < m["AbsDiff"] < 0.45 and m["AbsRel"] > 0.1


def test_eval_cli_depth_metrics_from_a_capture(tmp_path, capsys):
    from fixtures_capture import write_room_scene

    room, _ = _box_room_views()
    scene = write_room_scene(tmp_path / "scene", room)
    exact = box_mesh([0, 0, 0], [3.0, 2.6, 2.4])
    write_ply(tmp_path / "pred.ply", exact.vertices, exact.faces)
    rc = engine_main(["eval", str(tmp_path / "pred.ply"), str(tmp_path / "pred.ply"), "--depth", str(scene),
                      "--json", str(tmp_path / "m.json")])
    assert rc == 0
    assert "AbsRel" in capsys.readouterr().out
    depth = json.loads((tmp_path / "m.json").read_text())["depth"]["pred.ply"]
    assert depth["AbsRel"] < 0.01 and depth["complete"] > 0.99
    # --depth with nothing to read depth maps from is an error the user can act on
    assert engine_main(["eval", str(tmp_path / "pred.ply"), str(tmp_path / "pred.ply"), "--depth"]) == 1
    assert "--depth needs a capture folder" in capsys.readouterr().err


def test_the_truths_own_tsdf_meshed_is_scored_beside_the_prediction(tmp_path, capsys):
    """`--truth-tsdf`: the ceiling of a volumetric method. A box room with a 1 cm thin panel in it: the
    4 cm TSDF holds the walls but not the panel's two faces, so even this reference covers only the walls'
    share of the true area, 59 of 61 m^2 (what a reader must know before judging an area ratio)."""
    size, voxel, trunc = np.array([4.0, 3.0, 2.5]), 0.04, 0.12
    room = box_mesh([0, 0, 0], size)
    panel_v = np.array([[1, 1, 0.5], [2, 1, 0.5], [2, 1, 1.5], [1, 1, 1.5]], float)
    panel_v = np.concatenate([panel_v, panel_v + [0, 0.01, 0]])
    panel_f = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]]) + len(room.vertices)
    truth = Mesh(np.concatenate([room.vertices, panel_v]).astype(np.float32),
                 np.concatenate([room.faces, panel_f]).astype(np.int32))
    origin = np.full(3, -0.2)
    dims = np.ceil((size + 0.4) / voxel).astype(int) + 1
    centres = origin + (np.stack(np.meshgrid(*[np.arange(d) for d in dims], indexing="ij"), -1)) * voxel
    inside = np.minimum(centres, size - centres).min(-1)  # > 0 in the room: distance to the nearest wall
    tsdf = np.clip(-inside / trunc, -1, 1).astype(np.float32)
    weight = (inside > -0.15).astype(np.float32)
    TsdfVolume(tsdf, weight, origin, voxel, trunc).save(tmp_path / "tsdf.npz")
    write_ply(tmp_path / "gt.ply", truth.vertices, truth.faces)
    write_ply(tmp_path / "pred.ply", room.vertices, room.faces)

    rc = engine_main(["eval", str(tmp_path / "pred.ply"), str(tmp_path / "gt.ply"), "--observed",
                      str(tmp_path / "tsdf.npz"), "--truth-tsdf", "--json", str(tmp_path / "m.json")])

    assert rc == 0 and "truth's TSDF meshed" in capsys.readouterr().out
    surface = json.loads((tmp_path / "m.json").read_text())["surface"]
    assert surface["truth's TSDF meshed"]["area_ratio"] == pytest.approx(59 / 61, abs=0.015)
    assert surface["pred.ply"]["area_ratio"] == pytest.approx(59 / 61, abs=0.005)
    # Without the truth's TSDF there is no such row, and the user is told what to give.
    assert engine_main(["eval", str(tmp_path / "pred.ply"), str(tmp_path / "gt.ply"), "--truth-tsdf"]) == 1
    assert "--truth-tsdf needs the ground-truth TSDF" in capsys.readouterr().err
