"""End to end on a tiny synthetic capture with a seeded random network (CPU): CLI outputs, sidecar,
progress/cancel, the empty-result message, and settings that must change what the engine does."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from engine.__main__ import main
from engine.capture import load_capture
from engine.errors import Cancelled, PoseError
from engine.jobs import CancelToken
from engine.mesh_io import read_ply
from engine.recon import ReconSettings, TileState, plan_reconstruction, reconstruct
from engine.recon.driver import run_reconstruction
from engine.recon.network import load_network
from engine.recon.synthetic import make_synthetic_capture

# Tiny: 16 cm finest voxels, a 2 m clipped room, 160 px images, a few views per tile.
TINY = ["--method", "vortx", "--weights", "random", "--voxel-size", "0.16", "--tile-size", "8", "--views", "3", "--image-size", "160",
        "--colour-views", "3", "--max-room-size", "2", "2", "2", "--quiet"]
TINY_SETTINGS = dict(method="vortx", weights="random", voxel_size=0.16, tile_size=8, views=3, image_long_side=160,
                     colour_views=3, max_room_size=(2.0, 2.0, 2.0))


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("synthetic_room")
    make_synthetic_capture(path, room_size=(3.0, 3.0, 2.5), frames=8, image_size=(160, 120))
    return path


@pytest.fixture(scope="module")
def cli_runs(capture_dir, tmp_path_factory):
    """Two CLI runs: PLY with the tiny settings, a textured OBJ with a coarser voxel and fewer views."""
    out = tmp_path_factory.mktemp("out")
    ply, obj = out / "room_a.ply", out / "room_b.obj"
    assert main(["reconstruct", str(capture_dir), "--out", str(ply), *TINY]) == 0
    other = TINY + ["--voxel-size", "0.2", "--views", "1", "--texture-size", "512"]  # argparse: the last value wins
    assert main(["reconstruct", str(capture_dir), "--out", str(obj), *other]) == 0
    return ply, obj


def load_sidecar(mesh_path: Path) -> dict:
    return json.loads(mesh_path.with_suffix(".json").read_text())


def test_cli_writes_a_ply_and_a_consistent_sidecar(cli_runs, capture_dir):
    ply, _ = cli_runs
    side = load_sidecar(ply)
    mesh = read_ply(ply)
    assert len(mesh.faces) == side["mesh"]["faces"] > 0 and len(mesh.vertices) == side["mesh"]["vertices"]
    assert mesh.normals is not None and mesh.colors is not None
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-3)
    assert side["capture"] == str(capture_dir.resolve()) and side["settings"]["voxel_size"] == 0.16
    assert side["model"]["weights"] == "random (seed 0)" and side["message"] is None
    assert side["image_size"] == [160, 128]  # --image-size 160 for 160 x 120 photos, sides multiples of 16

    levels = side["levels"]
    assert [lv["label"] for lv in levels] == ["64 cm", "32 cm", "16 cm"]
    for upper, lower in zip(levels, levels[1:]):
        assert lower["voxels"] == 8 * upper["occupied"]  # every kept voxel has 8 children
    tiles = side["tile_details"]
    assert side["tiles"]["count"] == len(tiles) == int(np.prod(side["grid"]["tiles_per_axis"]))
    for level in levels:  # per-tile voxel counts add up to the level's total
        assert sum(t["voxels"].get(level["label"], 0) for t in tiles) == level["voxels"]
    assert side["tiles"]["views_per_tile"] == [len(t["views"]) for t in tiles]
    assert max(side["tiles"]["views_per_tile"]) <= 3
    assert set(side["timings_s"]) >= {"keyframes", "features", "fusion 64 cm", "3D CNN 64 cm", "fusion 16 cm",
                                       "3D CNN 16 cm", "mesh", "colour", "total"}
    assert side["memory"]["peak_rss_bytes"] > 0 and side["memory"]["process_max_rss_bytes"] > 0
    # The mesh lies inside the tile grid.
    lo = np.array(side["grid"]["origin"])
    hi = lo + np.array(side["grid"]["shape"]) * side["grid"]["voxel_size"]
    assert np.all(mesh.vertices >= lo - 1e-4) and np.all(mesh.vertices <= hi + 1e-4)


def test_voxel_size_and_view_count_change_what_the_engine_does(cli_runs):
    ply, obj = cli_runs
    a, b = load_sidecar(ply), load_sidecar(obj)
    assert obj.read_text().startswith("# written by VoRTX") and "\nf " in obj.read_text()
    assert b["settings"]["voxel_size"] == 0.2 and b["settings"]["views"] == 1
    assert [lv["label"] for lv in b["levels"]] == ["80 cm", "40 cm", "20 cm"]
    assert b["grid"]["voxel_size"] == 0.2 and a["grid"]["voxel_size"] == 0.16
    tile = b["tile_details"][0]
    np.testing.assert_allclose(np.subtract(tile["max"], tile["min"]), [8 * 0.2, 8 * 0.2, 48 * 0.2])
    assert [lv["voxels"] for lv in b["levels"]] != [lv["voxels"] for lv in a["levels"]]
    assert max(b["tiles"]["views_per_tile"]) == 1 < max(a["tiles"]["views_per_tile"])


def test_in_process_run_reports_stages_and_matches_the_cli(cli_runs, capture_dir):
    ply, _ = cli_runs
    stages: list[str] = []
    settings = ReconSettings(**TINY_SETTINGS)
    plan = plan_reconstruction(load_capture(capture_dir), settings)
    result = reconstruct(load_capture(capture_dir), settings,
                         progress=lambda stage, done, total: stages.append(stage) if not stages or stages[-1] != stage else None,
                         plan=plan)
    assert stages == ["features", "fusion 64 cm", "3D CNN 64 cm", "fusion 32 cm", "3D CNN 32 cm",
                      "fusion 16 cm", "3D CNN 16 cm", "mesh", "colour"]
    assert result.tiles is plan.tiles  # the plan's tiles were updated in place
    assert all(t.state in (TileState.DONE, TileState.EMPTY) for t in plan.tiles)
    # Same seed, same settings: the same run as the CLI's.
    assert [lv["voxels"] for lv in result.stats["levels"]] == [lv["voxels"] for lv in load_sidecar(ply)["levels"]]
    assert result.mesh.vertices.dtype == np.float32 and result.mesh.faces.dtype == np.int32
    assert result.mesh.colors.shape == result.mesh.vertices.shape


def test_nothing_occupied_gives_an_empty_mesh_with_the_reason(capture_dir):
    model, _, _ = load_network("random", 0, torch.device("cpu"))
    with torch.no_grad():
        model.output_layers["coarse"].kernel.zero_()  # every coarse logit 0: nothing passes "logit > 0"
    result = run_reconstruction(model, load_capture(capture_dir), ReconSettings(**TINY_SETTINGS), torch.device("cpu"))
    assert result.is_empty and result.mesh.vertices.shape == (0, 3)
    assert "no voxel was predicted occupied at 64 cm" in result.message
    assert "untrained/random" in result.message and "gravity" in result.message
    assert all(t.state is TileState.EMPTY for t in result.tiles)
    assert result.stats["levels"][0]["occupied"] == 0


def test_frames_without_poses_ask_for_pose_estimation(capture_dir):
    capture = load_capture(capture_dir)
    unposed = capture.with_frames([f.__class__(f.image_path, f.width, f.height, f.K, None) for f in capture.frames])
    with pytest.raises(PoseError, match="pose estimation"):
        reconstruct(unposed, ReconSettings(**TINY_SETTINGS))


def test_cancel_stops_between_tiles(capture_dir):
    token = CancelToken()

    def progress(stage: str, done: int, total: int) -> None:
        if stage.startswith("fusion"):
            token.cancel()

    with pytest.raises(Cancelled):
        reconstruct(load_capture(capture_dir), ReconSettings(**TINY_SETTINGS), progress=progress, cancel=token)


def test_default_weights_set_the_image_size_and_other_voxel_sizes_warn(capture_dir):
    from engine.model.weights import DEFAULT_WEIGHTS, read_config

    if not DEFAULT_WEIGHTS.is_file():
        pytest.skip(f"no default weights at {DEFAULT_WEIGHTS}")
    trained = read_config(DEFAULT_WEIGHTS)
    settings = ReconSettings(**{**TINY_SETTINGS, "weights": None, "image_long_side": None})
    result = reconstruct(load_capture(capture_dir), settings)
    assert result.stats["model"]["weights"] == str(DEFAULT_WEIGHTS)
    # 160 x 120 photos go to the network at the weights' training size (long side, multiples of 16).
    long_side = trained.image_long_side
    assert max(result.stats["image_size"]) == 16 * round(long_side / 16)
    assert any("trained with 4 cm voxels; 16 cm" in w for w in result.warnings)
    assert result.stats["warnings"] == result.warnings
