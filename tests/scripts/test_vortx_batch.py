"""scripts/vortx_batch.py end to end, as a user runs it: a subprocess with the bpy module and its own
BLENDER_USER_RESOURCES (so it mounts this checkout itself), on a tiny posed ScanNet-layout capture
with a seeded random network. The written .blend is inspected in another fresh process. A batch of
a good and a bad capture checks the per-capture reports, the exit status and that the bad one
leaves no .blend."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO
from fixtures_capture import intrinsics, ring_poses, write_photo_folder, write_scannet, write_transforms_json

BATCH = REPO / "scripts" / "vortx_batch.py"
# Tiny: 16 cm voxels, 8-voxel tiles, 3 views per tile, 160 px images, a 2 m room (tests/engine/recon/test_driver.py's numbers).
TINY = ["--method", "vortx", "--weights", "random", "--voxel-size", "0.16", "--tile-size", "8", "--views", "3", "--image-size", "160",
        "--colour-views", "3", "--max-room-size", "2", "2", "2"]

INSPECT_BLEND = textwrap.dedent(
    """
    import json, sys
    import bpy
    bpy.ops.wm.open_mainfile(filepath=sys.argv[1])
    objects = []
    for obj in bpy.data.objects:
        entry = {"name": obj.name, "type": obj.type, "frame": obj.get("vortx_frame"), "result": bool(obj.get("vortx_result"))}
        if obj.type == "MESH":
            coords = [0.0] * (3 * len(obj.data.vertices))
            obj.data.vertices.foreach_get("co", coords)
            world = [list(obj.matrix_world @ __import__("mathutils").Vector(coords[i:i + 3])) for i in range(0, len(coords), 3)]
            entry.update(faces=len(obj.data.polygons), colours=[a.name for a in obj.data.color_attributes], vertices=world)
        objects.append(entry)
    print("BLEND " + json.dumps({"objects": objects, "capture": bpy.context.scene.vortx.capture_path if hasattr(bpy.context.scene, "vortx") else None}))
    """
)


def run_batch(args: list[str], tmp_path: Path, timeout: int = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"))
    return subprocess.run([sys.executable, str(BATCH), *args], capture_output=True, text=True, timeout=timeout, env=env, cwd=tmp_path)


@pytest.fixture(scope="module")
def scannet_capture(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("batch") / "scan"
    write_scannet(folder, ring_poses(8, radius=1.0), intrinsics(100.0, 160, 120), (160, 120), depth=False)
    return folder


@pytest.mark.slow
def test_batch_writes_blend_with_cameras_and_mesh(scannet_capture: Path, tmp_path: Path) -> None:
    from engine.mesh_io import read_ply

    out, ply = tmp_path / "out" / "scene.blend", tmp_path / "out" / "mesh.ply"
    run = run_batch([str(scannet_capture), "--out", str(out), "--export", str(ply), *TINY], tmp_path)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    stages = [line for line in run.stdout.splitlines() if line.startswith("vortx [")]
    assert [s.split(":")[0] for s in stages] == ["vortx [1/5] import capture", "vortx [2/5] poses", "vortx [3/5] reconstruct",
                                                 "vortx [4/5] save", "vortx [5/5] export"], stages
    assert "8 frames (scannet), 8 posed" in stages[0]

    inspect = subprocess.run([sys.executable, "-c", INSPECT_BLEND, str(out)], capture_output=True, text=True, timeout=120,
                             env=dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "inspect-user")))
    line = next((l for l in inspect.stdout.splitlines() if l.startswith("BLEND ")), None)
    assert line is not None, inspect.stdout[-2000:] + inspect.stderr[-2000:]
    objects = json.loads(line[len("BLEND "):])["objects"]
    cameras = [o for o in objects if o["type"] == "CAMERA"]
    assert sorted(o["frame"] for o in cameras) == list(range(8))
    (result,) = [o for o in objects if o["result"]]
    assert result["type"] == "MESH" and result["faces"] > 0 and result["colours"]
    assert {o["type"] for o in objects} == {"CAMERA", "MESH"}  # nothing else (no default cube/light)

    # The exported PLY is the result mesh in world metres, Z up kept: same bounding box as in the .blend.
    mesh = read_ply(ply)
    world = np.array(result["vertices"])
    np.testing.assert_allclose(mesh.vertices.min(0), world.min(0), atol=1e-4)
    np.testing.assert_allclose(mesh.vertices.max(0), world.max(0), atol=1e-4)
    assert mesh.colors is not None and len(mesh.faces) >= result["faces"]

    # The report beside the .blend: what was done, with the numbers seen above.
    report = json.loads((tmp_path / "out" / "scene.report.json").read_text())
    assert report["status"] == "ok" and report["error"] is None and report["blend"] == str(out.resolve())
    assert report["frames"] == {"loaded": 8, "posed": 8, "used": 8, "skipped": [], "skip_reasons": []}
    assert report["poses"]["source"] == "given" and report["poses"]["scale_source"] == "metric capture"
    # The similarity from the capture's own coordinates to the result's world (metric capture: unchanged).
    frame = report["poses"]["frame"]
    assert frame["frame"] == "world" and frame["capture_to_world"]["matrix"] == np.eye(4).tolist()
    assert frame["output_to_capture"]["scale"] == 1.0
    assert report["mesh"]["faces"] == result["faces"] and report["mesh"]["export_bytes"] == ply.stat().st_size
    assert set(report["timings_s"]) == {"import capture", "poses", "reconstruct", "save", "export", "total"}
    assert report["settings"]["voxel_size"] == 0.16


def _assert_one_line_error(run: subprocess.CompletedProcess, expected: str) -> None:
    assert run.returncode != 0
    errors = [l for l in run.stderr.splitlines() if l.startswith("error: ")]
    assert len(errors) == 1 and run.stderr.rstrip().splitlines()[-1] == errors[0], run.stderr[-2000:]
    assert expected in errors[0], errors[0]


def test_batch_fails_on_an_empty_folder(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    run = run_batch([str(empty), "--out", str(tmp_path / "scene.blend")], tmp_path)
    _assert_one_line_error(run, f"capture folder {empty} is empty")
    assert not (tmp_path / "scene.blend").exists()
    report = json.loads((tmp_path / "scene.report.json").read_text())
    assert report["status"] == "failed" and f"capture folder {empty} is empty" in report["error"]
    assert report["failed_step"] == "import capture" and report["blend"] is None


def test_batch_without_poses_and_skip_poses_fails(tmp_path: Path) -> None:
    photos = tmp_path / "photos"
    write_photo_folder(photos, 3)
    run = run_batch([str(photos), "--out", str(tmp_path / "scene.blend"), "--skip-poses"], tmp_path)
    _assert_one_line_error(run, "has a camera pose and --skip-poses was given")
    assert not (tmp_path / "scene.blend").exists()


def test_batch_refuses_capture_coordinates_for_photos_without_poses(tmp_path: Path) -> None:
    """--frame capture is Blender's Coordinates = Capture: refused at import for photos without poses
    (structure from motion's poses have no capture coordinates), as `engine reconstruct` refuses it."""
    photos = tmp_path / "photos"
    write_photo_folder(photos, 3)
    run = run_batch([str(photos), "--out", str(tmp_path / "scene.blend"), "--frame", "capture"], tmp_path)
    _assert_one_line_error(run, "Coordinates 'Capture' is not available: no frame of the capture has a pose")
    assert not (tmp_path / "scene.blend").exists()
    assert json.loads((tmp_path / "scene.report.json").read_text())["failed_step"] == "import capture"


def test_batch_fails_on_a_missing_capture(tmp_path: Path) -> None:
    run = run_batch([str(tmp_path / "nowhere"), "--out", str(tmp_path / "scene.blend")], tmp_path, timeout=60)
    _assert_one_line_error(run, "nowhere does not exist")


@pytest.mark.slow
def test_batch_of_a_good_and_a_bad_capture_reports_both_and_fails(tmp_path: Path) -> None:
    """A folder of two captures: `good` (9 posed photos, one cut in half: skipped and reported) and
    `bad` (photos that are all unreadable). The good one is finished after the bad one failed."""
    rooms = tmp_path / "rooms"
    photos = write_scannet(rooms / "good", ring_poses(9, radius=1.0), intrinsics(100.0, 160, 120), (160, 120), depth=False)
    cut = photos[4]
    cut.write_bytes(cut.read_bytes()[:400])
    (rooms / "bad").mkdir(parents=True)
    for i in range(3):
        (rooms / "bad" / f"{i}.jpg").write_bytes(b"not a photo")
    out = tmp_path / "out"
    run = run_batch([str(rooms), "--out", str(out), "--export", ".ply", *TINY], tmp_path, timeout=600)
    assert run.returncode == 1, run.stdout[-3000:] + run.stderr[-3000:]
    assert f"error: {rooms / 'bad'}: " in run.stderr
    assert "vortx batch: 1 of 2 captures reconstructed; failed: " in run.stdout

    assert sorted(p.name for p in out.iterdir()) == ["bad.report.json", "good.blend", "good.ply", "good.report.json"]
    bad = json.loads((out / "bad.report.json").read_text())
    assert bad["status"] == "failed" and bad["failed_step"] == "import capture" and bad["blend"] is None
    assert "0.jpg" in bad["error"] and "at least 2 are needed" in bad["error"]

    good = json.loads((out / "good.report.json").read_text())
    assert good["status"] == "ok" and good["error"] is None and good["blend"] == str((out / "good.blend").resolve())
    assert good["frames"]["loaded"] == 8 and good["frames"]["used"] == 8 and good["frames"]["skipped"] == [cut.name]
    (reason,) = good["frames"]["skip_reasons"]
    assert f"{cut.name} (corrupt, truncated" in reason and reason in good["warnings"]
    assert good["poses"]["source"] == "given" and good["poses"]["scale_source"] == "metric capture"
    assert good["mesh"]["faces"] > 0 and good["mesh"]["export_bytes"] == (out / "good.ply").stat().st_size
    assert good["timings_s"]["reconstruct"] > 0 and good["timings_s"]["total"] >= good["timings_s"]["reconstruct"]


def test_batch_reconstructs_a_near_rigid_transforms_json(tmp_path: Path) -> None:
    """Issue 12: a tracker's transforms.json whose rotations are orthonormal only to ~2e-4
    (determinant ~0.9998) goes through the batch script: repaired with one warning, reconstructed."""
    rng = np.random.default_rng(0)
    stored = []
    for pose in ring_poses(8, radius=1.0):
        S = rng.uniform(-2e-4, 2e-4, (3, 3))
        pose = pose.copy()
        pose[:3, :3] = pose[:3, :3] @ (np.eye(3) + (S + S.T) / 2)
        stored.append(pose)
    assert max(abs(np.linalg.det(p[:3, :3]) - 1.0) for p in stored) > 1e-4
    capture = tmp_path / "tracker"
    write_photo_folder(capture / "images", 8, (160, 120), suffix=".jpg")
    write_transforms_json(capture / "transforms.json", [(f"images/frame{i}.jpg", p) for i, p in enumerate(stored)],
                          fl_x=100.0, fl_y=100.0, cx=80.0, cy=60.0, w=160, h=120)
    out = tmp_path / "out" / "tracker.blend"
    run = run_batch([str(capture), "--out", str(out), *TINY], tmp_path)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    report = json.loads((tmp_path / "out" / "tracker.report.json").read_text())
    assert report["status"] == "ok" and report["frames"]["used"] == 8 and report["mesh"]["faces"] > 0
    assert any("were not exactly rotations" in w for w in report["warnings"]), report["warnings"]
    assert out.is_file()
