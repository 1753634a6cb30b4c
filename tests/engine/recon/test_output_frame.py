"""`engine reconstruct --frame capture`: the mesh in the coordinates of the capture's own cameras.

The bundled demo room's photos with their true poses, moved by a known similarity (rotated, shifted
and scaled, as NeRF tools store a scene) into a transforms.json. The default result is in the Z-up
world the engine reconstructs in and needs an alignment to be compared with the truth; the
`--frame capture` result scores the same against the truth moved by that known similarity, with no
alignment step; and the similarity the default sidecar records maps the default mesh onto it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from engine.__main__ import main
from engine.capture import load_capture
from engine.eval import evaluate_mesh, mesh_points, observed_mask, point_metrics
from engine.mesh_io import Mesh, read_ply
from engine.poses import Similarity, umeyama
from engine.poses.prepare import prepare_capture
from engine.tsdf.volume import TsdfVolume
from fixtures_capture import rotation_about, write_transforms_json

DEMO = Path(__file__).resolve().parents[3] / "samples" / "demo_room"
# Coarse, quick stereo (~50 s of CPU per run): the test compares two frames of one result, not its quality.
FAST = ["--stereo", "fast", "--voxel-size", "0.08", "--stereo-image-size", "96", "--stereo-views", "8", "--stereo-planes", "32",
        "--colour-views", "1", "--quiet"]
# The capture's frame as a NeRF tool leaves it: tilted, shifted, in units of 1.25 m.
KNOWN = Similarity(rotation_about([1.0, 2.0, 0.5], 70.0), np.array([2.5, -1.0, 4.0]), 0.8)
THRESHOLD_M = 0.05  # the Atlas F-score threshold, in metres of the truth


def _loaded(sidecar: dict, key: str) -> Similarity:
    entry = sidecar["frame"][key]
    return Similarity(np.array(entry["rotation"]), np.array(entry["translation"]), entry["scale"])


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict:
    """The transforms.json capture, reconstructed once per frame."""
    folder = tmp_path_factory.mktemp("nerf_capture")
    K = np.loadtxt(DEMO / "truth" / "intrinsic" / "intrinsic_color.txt")[:3, :3]
    frames = [(str(p.resolve()), KNOWN.apply_pose(np.loadtxt(DEMO / "truth" / "pose" / f"{p.stem}.txt")))
              for p in sorted((DEMO / "images").glob("*.jpg"))]
    capture = write_transforms_json(folder / "transforms.json", frames, fl_x=K[0, 0], fl_y=K[1, 1], cx=K[0, 2],
                                    cy=K[1, 2], w=320, h=240)
    out = {}
    for frame in ("world", "capture"):
        mesh = folder / f"{frame}.ply"
        flags = [] if frame == "world" else ["--frame", "capture"]  # the default is the world
        assert main(["reconstruct", str(capture), "--out", str(mesh), *FAST, *flags]) == 0
        out[frame] = (read_ply(mesh), json.loads(mesh.with_suffix(".json").read_text()))
    out["capture_path"] = capture
    return out


def _scores_in_capture_frame(mesh: Mesh, truth: Mesh, observed: TsdfVolume) -> float:
    """F-score against the truth moved into the capture's frame, the threshold and sampling in its units;
    the truth's observed space moves with it (a fact of the truth, not an alignment of the result)."""
    s = KNOWN.scale
    back = KNOWN.inverse()
    pred = mesh_points(mesh, 0.02 * s, 0.01 * s)
    gt = KNOWN.apply_points(mesh_points(truth, 0.02, 0.01))
    pred = pred[observed_mask(back.apply_points(pred), observed)]
    gt = gt[observed_mask(back.apply_points(gt), observed)]
    return point_metrics(pred, gt, THRESHOLD_M * s).fscore


def test_capture_frame_mesh_scores_without_alignment_as_the_aligned_default(runs) -> None:
    truth = read_ply(DEMO / "truth" / "mesh_gt.ply")
    observed = TsdfVolume.load(DEMO / "truth" / "tsdf_gt.npz")
    world_mesh, world_side = runs["world"]
    capture_mesh, capture_side = runs["capture"]
    assert world_side["frame"]["frame"] == "world" and capture_side["frame"]["frame"] == "capture"

    # The default result, aligned to the truth as the demo does (Sim(3) of the camera centres).
    world = prepare_capture(load_capture(runs["capture_path"])).capture
    stems = [f.image_path.stem for f in world.frames]
    true_centres = np.stack([np.loadtxt(DEMO / "truth" / "pose" / f"{s}.txt")[:3, 3] for s in stems])
    to_truth = umeyama(np.stack([f.pose[:3, 3] for f in world.frames]), true_centres)
    aligned = Mesh(to_truth.apply_points(world_mesh.vertices).astype(np.float32), world_mesh.faces)
    aligned_f = evaluate_mesh(aligned, truth, observed).fscore

    capture_f = _scores_in_capture_frame(capture_mesh, truth, observed)
    # Measured: 0.457 aligned default, 0.459 capture frame; unaligned, the default mesh scores 0.0 in the capture's frame.
    assert aligned_f > 0.35
    assert abs(capture_f - aligned_f) < 0.03, (capture_f, aligned_f)
    assert _scores_in_capture_frame(world_mesh, truth, observed) < 0.1


def test_recorded_similarity_maps_the_default_mesh_onto_the_capture_frame_mesh(runs) -> None:
    world_mesh, world_side = runs["world"]
    capture_mesh, capture_side = runs["capture"]
    np.testing.assert_array_equal(world_mesh.faces, capture_mesh.faces)
    to_capture = _loaded(world_side, "output_to_capture")
    scale = KNOWN.scale
    np.testing.assert_allclose(to_capture.apply_points(world_mesh.vertices), capture_mesh.vertices, atol=1e-4 * scale)
    # ... and back, with the inverse it records beside it; the capture-frame run records the same pair.
    np.testing.assert_allclose(_loaded(world_side, "capture_to_output").apply_points(capture_mesh.vertices),
                               world_mesh.vertices, atol=1e-4)
    np.testing.assert_allclose(_loaded(capture_side, "capture_to_world").matrix(),
                               _loaded(world_side, "capture_to_world").matrix(), atol=1e-12)
    np.testing.assert_allclose(_loaded(capture_side, "capture_to_output").matrix(), np.eye(4), atol=1e-12)
    # Normals turn with the mesh.
    np.testing.assert_allclose(to_capture.apply_directions(world_mesh.normals), capture_mesh.normals, atol=1e-4)


def test_capture_frame_needs_poses_of_the_capture(tmp_path, capsys) -> None:
    from fixtures_capture import write_photo_folder

    photos = tmp_path / "photos"
    write_photo_folder(photos, 3)
    assert main(["reconstruct", str(photos), "--out", str(tmp_path / "room.ply"), "--frame", "capture"]) == 1
    err = capsys.readouterr().err
    assert "--frame capture:" in err and "no camera poses of its own" in err and "--frame world" in err


def test_frame_records_map_both_ways_and_say_when_there_is_no_capture_frame() -> None:
    from dataclasses import replace

    from engine.capture.model import Capture, Frame
    from engine.poses.prepare import PreparedCapture
    from engine.recon.output_frame import frame_record, moved_mesh, similarity_from_record, world_to_output

    K = np.array([[250.0, 0, 160], [0, 250.0, 120], [0, 0, 1]])
    level = [np.eye(4) for _ in range(3)]
    for i, pose in enumerate(level):
        pose[:3, 3] = [i, 0.0, 1.5]
    frames = [Frame(Path(f"{i}.jpg"), 320, 240, K, KNOWN.apply_pose(p)) for i, p in enumerate(level)]
    prepared = prepare_capture(Capture(Path("c"), "transforms", frames, metric=False))
    record = frame_record(prepared, "capture")
    to_world = similarity_from_record(record["capture_to_world"])
    for frame, moved in zip(frames, prepared.capture.frames):
        np.testing.assert_allclose(to_world.apply_pose(frame.pose), moved.pose, atol=1e-9)
    back = similarity_from_record(record["world_to_capture"])
    np.testing.assert_allclose(back.matrix() @ to_world.matrix(), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(similarity_from_record(record["capture_to_output"]).matrix(), np.eye(4), atol=1e-9)
    # A mesh moved to the capture frame and back is where it was; normals stay unit length.
    mesh = Mesh(np.random.default_rng(0).random((5, 3)).astype(np.float32), np.array([[0, 1, 2]], np.int32),
                normals=np.tile(np.float32([0, 0, 1]), (5, 1)))
    there = moved_mesh(mesh, world_to_output(prepared, "capture"))
    np.testing.assert_allclose(moved_mesh(there, to_world).vertices, mesh.vertices, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(there.normals, axis=1), 1.0, atol=1e-6)

    # Structure from motion's poses: no capture frame; the record says so, and --frame capture is refused.
    sfm = replace(PreparedCapture(prepared.capture, "camera height", "scaled"), sfm=object())  # type: ignore[arg-type]
    none = frame_record(sfm, "world")
    assert none["capture_to_world"] is None and none["output_to_capture"] is None
    assert "structure from motion" in none["note"]
    with pytest.raises(Exception, match="--frame capture: structure from motion estimated the poses"):
        world_to_output(sfm, "capture")


def test_a_record_made_again_for_another_frame_or_a_moved_world() -> None:
    """`record_in_frame` (Blender's Coordinates switch and Set Scale): the same similarities, another
    output; after the world is scaled the capture maps to the scaled world; no capture frame, no Capture."""
    from engine.errors import VortxError
    from engine.recon.output_frame import record_in_frame, similarity_from_record, similarity_record

    world = similarity_record(KNOWN, "world", Similarity.identity())
    capture = record_in_frame(world, "capture")
    assert capture["frame"] == "capture" and capture["capture_to_world"] == world["capture_to_world"]
    np.testing.assert_allclose(similarity_from_record(capture["world_to_output"]).matrix(),
                               KNOWN.inverse().matrix(), atol=1e-12)
    np.testing.assert_allclose(similarity_from_record(capture["capture_to_output"]).matrix(), np.eye(4), atol=1e-12)
    assert record_in_frame(capture, "world") == world
    doubled = record_in_frame(capture, "capture", Similarity(np.eye(3), np.zeros(3), 2.0))
    np.testing.assert_allclose(similarity_from_record(doubled["capture_to_world"]).matrix(),
                               np.diag([2.0, 2.0, 2.0, 1.0]) @ KNOWN.matrix(), atol=1e-12)
    none = similarity_record(None, "world", Similarity.identity(), "no frame of the capture has a pose")
    assert record_in_frame(none, "world") == none
    with pytest.raises(VortxError, match="^no frame of the capture has a pose$"):
        record_in_frame(none, "capture")
