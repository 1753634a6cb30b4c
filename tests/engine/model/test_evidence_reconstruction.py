"""The inference driver with stereo-evidence weights: it computes the stereo depth maps once, feeds
them to the network, and an untrained evidence network gives the classical fusion surface of those
maps. Exact depth stands in for stereo here (stereo_depth_maps is replaced), so the test is about
the plumbing and the residual start, not about matching quality (tests/engine/stereo covers that)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

import engine.recon.stereo_fusion as stereo_fusion
from engine.capture import load_capture
from engine.model.config import StereoEvidenceConfig, VortxConfig
from engine.model.vortx import VortxNet
from engine.recon.driver import run_reconstruction
from engine.recon.plan import plan_reconstruction
from engine.recon.settings import ReconSettings
from engine.recon.synthetic import make_synthetic_capture, render_box_room
from engine.recon.stereo_fusion import run_stereo_fusion
from engine.stereo.depth_maps import DepthMap

ROOM = (3.0, 3.0, 2.5)
VOXEL = 0.08


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    path = tmp_path_factory.mktemp("evidence_capture")
    make_synthetic_capture(path, room_size=ROOM, frames=12, image_size=(128, 96), radius=0.5, outward_deg=45.0)
    return load_capture(path)


def exact_depth_maps(capture, plan, options, progress=None, cancel=None, stages=None):
    maps = []
    for k, frame in enumerate(plan.keyframes[::2]):
        _, depth = render_box_room(frame.K, frame.pose, (frame.width, frame.height), np.asarray(ROOM))
        maps.append(DepthMap(2 * k, depth, np.ones_like(depth), frame.K, frame.pose, np.zeros(0, np.int64), (0.2, 5.0)))
    return maps


def test_untrained_evidence_network_gives_the_classical_fusion_surface(capture, monkeypatch):
    monkeypatch.setattr(stereo_fusion, "stereo_depth_maps", exact_depth_maps)
    torch.manual_seed(0)
    torch.set_num_threads(1)
    settings = ReconSettings(method="vortx", voxel_size=VOXEL, colour_views=0, image_long_side=128, views=6)
    config = VortxConfig(feature_channels=(16, 8, 8), unet_base_widths=(8, 4, 4), voxel_size=VOXEL,
                         stereo_evidence=StereoEvidenceConfig(), image_long_side=128)
    net = VortxNet(config).eval()
    plan = plan_reconstruction(capture, settings)
    learned = run_reconstruction(net, capture, settings, torch.device("cpu"), plan=plan)
    maps = exact_depth_maps(capture, plan, None)
    assert learned.stats["stereo"]["references"] == len(maps)
    classical_run = run_stereo_fusion(capture, dataclasses.replace(settings, method="stereo"), torch.device("cpu"),
                                      plan=plan_reconstruction(capture, settings))
    classical = classical_run.mesh
    # The confidence layer judges both alike: what no map observed is what the network would have added.
    assert learned.stats["evidence"]["completed"] == classical_run.stats["evidence"]["unobserved"]
    assert learned.stats["evidence"]["seen_by_3_plus"] == classical_run.stats["evidence"]["seen_by_3_plus"]
    a, b = learned.mesh.vertices, classical.vertices
    assert len(b) > 500
    # The same mesh: same vertex count and every vertex of each within a hundredth of a voxel of the other's.
    assert len(a) == len(b)
    d_ab, _ = cKDTree(b).query(a)
    d_ba, _ = cKDTree(a).query(b)
    assert d_ab.max() < 0.01 * VOXEL and d_ba.max() < 0.01 * VOXEL
