"""The classical stereo method end to end, from the CLI: the bundled demo photos with their true
poses -> a mesh that matches the true room, a sidecar that says what stereo did, no weights needed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from engine.__main__ import main
from engine.errors import Cancelled
from engine.jobs import CancelToken
from engine.mesh_io import read_ply
from engine.recon import ReconSettings, reconstruct
from engine.capture.model import Capture, Frame
from engine.capture.writers import write_scannet
from engine.eval import evaluate_mesh
from engine.tsdf.volume import TsdfVolume

DEMO = Path(__file__).resolve().parents[3] / "samples" / "demo_room"
# The default matcher (PatchMatch) on fewer, smaller depth maps than the defaults.
FAST = ["--voxel-size", "0.08", "--stereo-image-size", "128", "--stereo-views", "12", "--colour-views", "3", "--quiet"]


@pytest.fixture(scope="module")
def demo_posed(tmp_path_factory) -> Path:
    """The bundled demo photos with their true poses, in the ScanNet layout the CLI reads."""
    K = np.loadtxt(DEMO / "truth" / "intrinsic" / "intrinsic_color.txt")[:3, :3]
    frames = [Frame(p, 320, 240, K, np.loadtxt(DEMO / "truth" / "pose" / f"{p.stem}.txt").reshape(4, 4))
              for p in sorted((DEMO / "images").glob("*.jpg"))]
    out = tmp_path_factory.mktemp("demo_posed")
    write_scannet(Capture(DEMO, "images", frames, metric=True), out, overwrite=True)
    return out


def test_stereo_method_reconstructs_the_demo_room(demo_posed: Path, tmp_path: Path) -> None:
    out = tmp_path / "room.ply"
    assert main(["reconstruct", str(demo_posed), "--out", str(out), "--method", "stereo", *FAST]) == 0
    mesh = read_ply(out)
    truth = read_ply(DEMO / "truth" / "mesh_gt.ply")
    metrics = evaluate_mesh(mesh, truth, TsdfVolume.load(DEMO / "truth" / "tsdf_gt.npz"))
    # Measured with these fast settings: precision ~0.7, recall ~0.4 (the defaults reach 0.83 / 0.64).
    assert metrics.prec > 0.55 and metrics.recall > 0.25
    side = json.loads(out.with_suffix(".json").read_text())
    assert side["model"]["method"] == "stereo" and side["settings"]["method"] == "stereo"
    assert side["stereo"]["references"] == 12 and side["stereo"]["image_size"] == [128, 96]
    assert 0.3 < side["stereo"]["completeness_mean"] <= 1.0
    assert {"stereo depth", "TSDF fusion", "mesh", "colour"} <= set(side["timings_s"])
    assert mesh.colors is not None and np.ptp(mesh.colors) > 0.2, "coloured from the photos, not grey"
    # A 3 m high room: its tilted frusta span more than 6 m in z, its stereo depths do not (no false warning).
    assert not [w for w in side["warnings"] if "maximum room size" in w], side["warnings"]


def test_stereo_method_can_be_cancelled(demo_posed: Path) -> None:
    from engine.capture import load_capture

    token = CancelToken()
    calls = []

    def progress(stage: str, done: int, total: int) -> None:
        calls.append(stage)
        if stage == "patchmatch" and done == 2:  # the default matcher's progress
            token.cancel()

    with pytest.raises(Cancelled):
        reconstruct(load_capture(demo_posed), ReconSettings(voxel_size=0.08, stereo_views=10, stereo_image_size=96),
                    progress=progress, cancel=token)
    assert "patchmatch" in calls


def test_untrained_evidence_weights_give_the_stereo_methods_mesh_on_the_demo(demo_posed: Path, tmp_path: Path) -> None:
    """The learned method starts exactly at classical fusion (its heads' last layers are zero): on the demo
    photos, through the CLI, the same vertices and the same F-score as the default method."""
    import torch
    from scipy.spatial import cKDTree

    from engine.model.config import StereoEvidenceConfig, VortxConfig
    from engine.model.vortx import VortxNet
    from engine.model.weights import save_weights

    torch.manual_seed(0)
    config = VortxConfig(feature_channels=(16, 8, 8), unet_base_widths=(8, 4, 4), voxel_size=0.08, image_long_side=128,
                         stereo_evidence=StereoEvidenceConfig())
    weights = save_weights(VortxNet(config), config, tmp_path / "untrained.safetensors")
    meshes = {}
    for method, extra in (("stereo", []), ("vortx", ["--weights", str(weights), "--views", "8"])):
        out = tmp_path / f"{method}.ply"
        # The fast matcher: the equivalence holds for any depth maps, and these cost a fifth of PatchMatch's.
        assert main(["reconstruct", str(demo_posed), "--out", str(out), "--method", method, *FAST, "--stereo", "fast",
                     *extra]) == 0
        meshes[method] = read_ply(out)
    learned, classical = meshes["vortx"].vertices, meshes["stereo"].vertices
    assert len(classical) > 2000
    voxel = 0.08
    assert np.all(cKDTree(classical).query(learned)[0] < voxel)
    assert np.all(cKDTree(learned).query(classical)[0] < voxel)
    truth = read_ply(DEMO / "truth" / "mesh_gt.ply")
    trim = TsdfVolume.load(DEMO / "truth" / "tsdf_gt.npz")
    scores = {m: evaluate_mesh(mesh, truth, trim).fscore for m, mesh in meshes.items()}
    assert abs(scores["vortx"] - scores["stereo"]) < 0.005, scores


def test_sensor_depth_gives_the_maps_of_the_photos_that_have_it(demo_posed: Path, tmp_path: Path) -> None:
    """The demo photos with a LiDAR-like depth per photo (the true room rendered at 80 x 60, confident
    except on a border, as a phone's is): no PatchMatch map for them, and a mesh that matches the true
    room better than stereo's from the same photos; with --no-sensor-depth, stereo as before."""
    import cv2
    from dataclasses import replace

    from engine.capture import load_capture
    from engine.capture.model import SensorDepth
    from engine.geometry.depth_render import render_depth

    capture = load_capture(demo_posed)
    truth = read_ply(DEMO / "truth" / "mesh_gt.ply")
    frames = []
    for i, frame in enumerate(capture.frames):
        size = (80, 60)
        K = frame.K * np.array([[size[0] / frame.width], [size[1] / frame.height], [1.0]])
        depth = render_depth(truth.vertices, truth.faces, K, frame.pose, size)
        depth = np.where(np.isfinite(depth), depth, 0.0)
        confidence = np.full(depth.shape, 2, np.uint8)
        confidence[:, :4] = 0  # a low-confidence border: no depth taken there
        cv2.imwrite(str(tmp_path / f"depth_{i}.png"), np.round(depth * 1000).astype(np.uint16))
        cv2.imwrite(str(tmp_path / f"conf_{i}.png"), confidence)
        frames.append(replace(frame, sensor_depth=SensorDepth(tmp_path / f"depth_{i}.png", "png_mm",
                                                              tmp_path / f"conf_{i}.png")))
    with_depth = capture.with_frames(frames)
    settings = ReconSettings(voxel_size=0.08, stereo_image_size=128, stereo_views=12, colour_views=3)
    scores = {}
    for sensor_depth in (True, False):
        result = reconstruct(with_depth, replace(settings, sensor_depth=sensor_depth))
        scores[sensor_depth] = evaluate_mesh(result.mesh, truth, TsdfVolume.load(DEMO / "truth" / "tsdf_gt.npz"))
        stereo = result.stats["stereo"]
        if sensor_depth:
            assert stereo["stages_s"] == {} and stereo["sensor_depth_maps"] == stereo["references"] == len(frames)
        else:
            assert stereo["references"] == 12 and "sensor_depth_maps" not in stereo
    # Measured: F 0.83 with the sensor depth, 0.61 with stereo alone (8 cm voxels, 12 small depth maps).
    assert scores[True].fscore > 0.78 and scores[True].fscore > scores[False].fscore + 0.12, scores
