"""The inference driver with stereo-evidence weights: it computes the stereo depth maps once, feeds
them to the network, and an untrained evidence network gives the classical fusion surface of those
maps. Exact depth stands in for stereo here (stereo_depth_maps is replaced), so the test is about
the plumbing and the residual start, not about matching quality (tests/engine/stereo covers that)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

import engine.recon.stereo_fusion as stereo_fusion
from engine.capture import load_capture
from engine.model.config import StereoEvidenceConfig, VortxConfig
from engine.model.vortx import VortxNet
from engine.recon.driver import run_reconstruction
from engine.recon.mesh import extract_mesh
from engine.recon.plan import plan_reconstruction
from engine.recon.settings import ReconSettings
from engine.recon.synthetic import make_synthetic_capture, render_box_room
from engine.stereo import DepthMap, fuse_depth_maps

ROOM = (3.0, 3.0, 2.5)
VOXEL = 0.08


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    path = tmp_path_factory.mktemp("evidence_capture")
    make_synthetic_capture(path, room_size=ROOM, frames=12, image_size=(128, 96), radius=0.5, outward_deg=45.0)
    return load_capture(path)


def exact_depth_maps(capture, plan, options, progress=None, cancel=None):
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
    origin = plan.grid.origin
    dims = np.ceil((plan.bounds.maximum - origin) / VOXEL).astype(int) + 1
    tsdf, weight = fuse_depth_maps(maps, origin, dims, VOXEL)
    observed = weight >= 1
    classical = extract_mesh(np.argwhere(observed), tsdf[observed], origin, VOXEL)
    a, b = learned.mesh.vertices, classical.vertices
    assert len(a) > 500 and len(b) > 500
    # Same surface: nearly every vertex of each mesh lies within a voxel of the other mesh.
    d_ab, _ = cKDTree(b).query(a)
    d_ba, _ = cKDTree(a).query(b)
    assert np.mean(d_ab < VOXEL) > 0.95
    # Measured 0.86: coarse voxels whose corner no map reaches are pruned, losing some surface at the
    # edges of the observed space (the coarse prior samples one corner per 16 cm voxel).
    assert np.mean(d_ba < VOXEL) > 0.8
