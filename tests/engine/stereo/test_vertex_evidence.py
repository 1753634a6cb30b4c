"""The confidence layer: how many depth maps saw each vertex at their depth, with what confidence, and
whether the network completed it. A hand-built case: a plane 2 m in front of three cameras, one of which
has an occluder over part of the plane and one a hole in its depth."""

from __future__ import annotations

import numpy as np
import pytest

from engine.stereo.depth_maps import DepthMap
from engine.observation import ADDED, COMPLETED, OBSERVATIONS, STEREO_CONFIDENCE
from engine.mesh_io import Mesh
from engine.stereo.vertex_evidence import attach_evidence, evidence_summary, observe_vertices, vertex_evidence

PLANE_Z = 2.0  # world z of the plane; cameras at z = 0 look along +z (OpenCV axes, identity rotation)
SIZE = (80, 60)  # (w, h) of each depth map
K = np.array([[60.0, 0.0, 40.0], [0.0, 60.0, 30.0], [0.0, 0.0, 1.0]])
TRUNCATION = 0.12


def camera(x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x
    return pose


def depth_map(x: float, depth: np.ndarray, confidence: float) -> DepthMap:
    conf = np.where(depth > 0, confidence, 0.0).astype(np.float32)
    return DepthMap(0, depth.astype(np.float32), conf, K, camera(x), np.zeros(0, np.int64), (0.5, 5.0))


def plane_vertices() -> np.ndarray:
    """A 9 x 7 grid on the plane within every camera's view; x and y avoid the occluder and hole edges."""
    xs, ys = np.meshgrid(np.linspace(-0.83, 0.77, 9), np.linspace(-0.63, 0.57, 7))
    return np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, PLANE_Z)], 1).astype(np.float32)


@pytest.fixture
def three_views():
    w, h = SIZE
    full = np.full((h, w), PLANE_Z)
    seen_by_a = depth_map(-0.1, full, 0.9)
    # B: a box 1 m from the camera covers the image's left half (world x < 0.1 on the plane).
    occluded = full.copy()
    occluded[:, : w // 2] = 1.0
    seen_by_b = depth_map(0.1, occluded, 0.6)
    # C: no depth in the image's top half (world y < 0 on the plane): textureless there.
    holed = full.copy()
    holed[: h // 2] = 0.0
    seen_by_c = depth_map(0.0, holed, 0.75)
    return [seen_by_a, seen_by_b, seen_by_c]


def expected(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Observations and mean confidence from the construction: A sees all, B where x > 0.1, C where y > 0."""
    in_b = vertices[:, 0] > 0.1
    in_c = vertices[:, 1] > 0.0
    count = 1 + in_b.astype(float) + in_c.astype(float)
    total = 0.9 + 0.6 * in_b + 0.75 * in_c
    return count, total / count


def test_a_plane_seen_by_three_views_one_occluded_one_with_a_hole(three_views) -> None:
    vertices = plane_vertices()
    count, confidence = observe_vertices(vertices, three_views, TRUNCATION)
    want_count, want_confidence = expected(vertices)
    assert set(np.unique(want_count)) == {1.0, 2.0, 3.0}  # the case covers every combination
    np.testing.assert_array_equal(count, want_count)
    np.testing.assert_allclose(confidence, want_confidence, atol=1e-6)


def test_only_vertices_at_the_depth_are_observed(three_views) -> None:
    """Off the plane by more than the truncation (in front: the view saw through it; behind: hidden),
    outside every view, or behind the cameras: nobody observed it."""
    points = np.float32([
        [0.3, 0.3, PLANE_Z - 0.5],  # floating in the free space every view saw through
        [0.3, 0.3, PLANE_Z + 0.5],  # behind the plane
        [0.3, 0.3, PLANE_Z - 0.1],  # within the truncation: still observed by all three
        [9.0, 0.3, PLANE_Z],  # outside every image
        [0.3, 0.3, -1.0],  # behind the cameras
    ])
    count, confidence = observe_vertices(points, three_views, TRUNCATION)
    np.testing.assert_array_equal(count, [0, 0, 3, 0, 0])
    np.testing.assert_allclose(confidence, [0, 0, (0.9 + 0.6 + 0.75) / 3, 0, 0], atol=1e-6)


def test_completed_only_where_a_network_filled_in_unobserved_surface(three_views) -> None:
    vertices = np.concatenate([plane_vertices(), np.float32([[0.3, 0.3, PLANE_Z + 0.5]])])
    network = vertex_evidence(vertices, three_views, TRUNCATION, network_completes=True)
    fusion = vertex_evidence(vertices, three_views, TRUNCATION, network_completes=False)
    assert set(network) == {OBSERVATIONS, STEREO_CONFIDENCE, COMPLETED}
    assert all(a.dtype == np.float32 and a.shape == (len(vertices),) for a in network.values())
    np.testing.assert_array_equal(network[COMPLETED], (network[OBSERVATIONS] == 0).astype(np.float32))
    assert network[COMPLETED][-1] == 1 and network[COMPLETED][:-1].sum() == 0
    assert not fusion[COMPLETED].any()
    summary = evidence_summary(network)
    assert summary["unobserved"] == pytest.approx(1 / len(vertices), abs=1e-4)
    assert summary["completed"] == summary["unobserved"]


def test_attach_evidence_sets_the_mesh_attributes_with_the_fusion_truncation(three_views) -> None:
    """At 4 cm voxels the truncation is 12 cm: a vertex 10 cm off the plane is observed, 20 cm is not."""
    vertices = np.float32([[0.3, 0.3, PLANE_Z - 0.10], [0.3, 0.3, PLANE_Z - 0.20]])
    mesh = Mesh(vertices, np.int32([[0, 1, 1]]), attributes={"kept": np.float32([7, 8])})
    summary = attach_evidence(mesh, three_views, voxel_size=0.04, network_completes=True)
    np.testing.assert_array_equal(mesh.attributes[OBSERVATIONS], [3, 0])
    np.testing.assert_array_equal(mesh.attributes[COMPLETED], [0, 1])
    np.testing.assert_array_equal(mesh.attributes["kept"], [7, 8])
    assert summary["seen_by_3_plus"] == 0.5 and summary["completed"] == 0.5


def test_the_stereo_method_writes_the_layer_into_its_ply(tmp_path) -> None:
    """End to end: `engine reconstruct --method stereo` on a ray-cast box room; every vertex the fusion
    placed carries its evidence, most of it seen by several depth maps, none completed."""
    import json

    from engine.__main__ import main
    from engine.mesh_io import read_ply
    from engine.recon.synthetic import make_synthetic_capture

    make_synthetic_capture(tmp_path / "room", room_size=(3.0, 3.0, 2.5), frames=16, image_size=(160, 120),
                           radius=0.5, outward_deg=45.0)
    out = tmp_path / "room.ply"
    assert main(["reconstruct", str(tmp_path / "room"), "--out", str(out), "--method", "stereo", "--stereo", "fast",
                 "--voxel-size", "0.08", "--stereo-views", "8", "--stereo-planes", "32", "--colour-views", "2", "--quiet"]) == 0
    mesh = read_ply(out)
    # The finishing stage (Room by default) adds its own mark of the faces it added.
    assert set(mesh.attributes) == {OBSERVATIONS, STEREO_CONFIDENCE, COMPLETED, ADDED}
    observations, confidence = mesh.attributes[OBSERVATIONS], mesh.attributes[STEREO_CONFIDENCE]
    assert observations.max() <= 8 and (observations >= 1).mean() > 0.6
    seen = observations > 0
    assert confidence[seen].min() >= 0.3 and confidence[seen].max() <= 1.0 and not confidence[~seen].any()
    assert not mesh.attributes[COMPLETED].any()
    sidecar = json.loads(out.with_suffix(".json").read_text())
    assert sidecar["evidence"]["completed"] == 0.0 and "evidence" in sidecar["timings_s"]
    assert sidecar["evidence"]["unobserved"] == pytest.approx(float((observations == 0).mean()), abs=1e-4)
