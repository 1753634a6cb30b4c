"""scripts/vortx_batch.py end to end, as a user runs it: a subprocess with the bpy module and its own
BLENDER_USER_RESOURCES (so it mounts this checkout itself), on a tiny posed ScanNet-layout capture
with a seeded random network. The written .blend is inspected in another fresh process."""

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
from fixtures_capture import intrinsics, ring_poses, write_photo_folder, write_scannet

BATCH = REPO / "scripts" / "vortx_batch.py"
# Tiny: 16 cm voxels, 8-voxel tiles, 3 views per tile, 160 px images, a 2 m room (test_recon_driver's numbers).
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


def test_arguments_after_double_dash_or_directly() -> None:
    from vortx_batch import parse_arguments, script_arguments

    blender_argv = ["blender", "--background", "--python", "scripts/vortx_batch.py", "--", "cap", "--out", "a.blend"]
    python_argv = ["scripts/vortx_batch.py", "cap", "--out", "a.blend"]
    assert script_arguments(blender_argv) == script_arguments(python_argv) == ["cap", "--out", "a.blend"]
    args = parse_arguments(["cap", "--out", "a.blend", "--export", "m.GLB", "--device", "cuda"])
    assert args.export == Path("m.GLB") and args.device == "cuda" and args.weights is None and args.views == 60
    with pytest.raises(SystemExit):
        parse_arguments(["cap", "--out", "a.obj"])


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


def test_batch_without_poses_and_skip_poses_fails(tmp_path: Path) -> None:
    photos = tmp_path / "photos"
    write_photo_folder(photos, 3)
    run = run_batch([str(photos), "--out", str(tmp_path / "scene.blend"), "--skip-poses"], tmp_path)
    _assert_one_line_error(run, "has a camera pose and --skip-poses was given")
    assert not (tmp_path / "scene.blend").exists()


def test_batch_fails_on_a_missing_capture(tmp_path: Path) -> None:
    run = run_batch([str(tmp_path / "nowhere"), "--out", str(tmp_path / "scene.blend")], tmp_path, timeout=60)
    _assert_one_line_error(run, "nowhere does not exist")
