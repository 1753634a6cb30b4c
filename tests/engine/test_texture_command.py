"""`engine reconstruct --out room.glb` and `engine texture CAPTURE MESH --out ...` as a user runs them,
on the bundled demo photos with their true poses (stereo method at small settings, small texture)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.__main__ import main
from engine.mesh_io import read_ply
from engine.capture import Capture, Frame
from engine.capture.writers import write_scannet
from fixtures_gltf import assert_valid_gltf  # the Khronos glTF-Validator on every GLB written here
from fixtures_texture import read_glb  # an independent reader: the writer is not checked with its own code

DEMO = Path(__file__).resolve().parents[2] / "samples" / "demo_room"
FAST = ["--stereo", "fast", "--voxel-size", "0.08", "--stereo-image-size", "128", "--stereo-views", "10", "--stereo-planes", "40",
        "--colour-views", "6", "--texture-size", "512", "--face-budget", "3000", "--quiet"]


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    """Every third demo photo with its true pose, in the ScanNet layout the CLI reads."""
    K = np.loadtxt(DEMO / "truth" / "intrinsic" / "intrinsic_color.txt")[:3, :3]
    frames = [Frame(p, 320, 240, K, np.loadtxt(DEMO / "truth" / "pose" / f"{p.stem}.txt").reshape(4, 4))
              for p in sorted((DEMO / "images").glob("*.jpg"))[::3]]
    out = tmp_path_factory.mktemp("room")
    write_scannet(Capture(DEMO, "images", frames, metric=True), out, overwrite=True)
    return out


def glb_texture(path: Path) -> np.ndarray:
    document, binary = read_glb(path)
    view = document["bufferViews"][document["images"][0]["bufferView"]]
    png = binary[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)


def test_reconstruct_to_glb_writes_a_light_textured_room(room, tmp_path, capsys):
    out = tmp_path / "room.glb"
    assert main(["reconstruct", str(room), "--out", str(out), *FAST]) == 0
    assert_valid_gltf(out)
    document, _ = read_glb(out)
    faces = document["accessors"][document["meshes"][0]["primitives"][0]["indices"]]["count"] // 3
    assert 0 < faces <= 3000
    texture = glb_texture(out)
    assert texture.shape == (512, 512, 3) and texture.std() > 5  # photo content, not a flat fill
    full = read_ply(out.with_suffix(".ply"))  # the full mesh beside it: vertex colours, confidence layer
    assert len(full.faces) >= faces and full.colors is not None and "observations" in full.attributes
    side = json.loads(out.with_suffix(".json").read_text())
    assert side["files"] == [str(out), str(out.with_suffix(".ply"))]
    assert side["texture"]["faces"] == faces and side["texture"]["texels_seen"] > 0.5 * side["texture"]["texels"]
    assert "512 px texture" in capsys.readouterr().out


def test_texture_command_bakes_an_existing_mesh(room, tmp_path, capsys):
    ply = tmp_path / "room.ply"
    untextured = FAST[:FAST.index("--texture-size")] + ["--quiet"]  # a PLY has no texture: those flags are refused
    assert main(["reconstruct", str(room), "--out", str(ply), *untextured]) == 0
    full_faces = len(read_ply(ply).faces)
    out = tmp_path / "textured.obj"
    assert main(["texture", str(room), str(ply), "--out", str(out), "--texture-size", "512", "--face-budget", "0",
                 "--voxel-size", "0.08", "--quiet"]) == 0
    lines = out.read_text().splitlines()
    vr = json.loads(out.with_suffix(".json").read_text())["texture"]["vr"]
    # Budget 0: no decimation; only specks under 0.1 % of the faces were dropped.
    assert vr["faces_in"] == full_faces and vr["faces"] == vr["faces_after_pieces"]
    assert sum(line.startswith("f ") for line in lines) == vr["faces"] > 0.8 * full_faces
    assert (tmp_path / "textured.mtl").is_file() and (tmp_path / "textured_texture.png").is_file()
    assert "wrote textured.obj, textured.mtl, textured_texture.png" in capsys.readouterr().out


def test_texture_command_errors_name_what_to_fix(room, tmp_path, capsys):
    assert main(["texture", str(room), str(tmp_path / "missing.ply"), "--out", str(tmp_path / "x.glb")]) == 1
    assert "give the mesh as a .ply file" in capsys.readouterr().err
    assert main(["texture", str(room), str(tmp_path / "missing.ply"), "--out", str(tmp_path / "x.fbx")]) == 1
    assert "written as .glb, .obj or .usdz" in capsys.readouterr().err


def test_texture_command_writes_a_headsets_glb_with_its_preview_and_a_usdz(room, tmp_path, capsys):
    from pxr import Usd, UsdGeom

    ply = tmp_path / "room.ply"
    untextured = FAST[:FAST.index("--texture-size")] + ["--quiet"]
    assert main(["reconstruct", str(room), "--out", str(ply), *untextured]) == 0
    bake = ["--texture-size", "512", "--voxel-size", "0.08", "--quiet"]
    out = tmp_path / "room.glb"
    assert main(["texture", str(room), str(ply), "--out", str(out), "--headset", "standalone", "--preview", *bake]) == 0
    assert "(standalone headset preset)" in capsys.readouterr().out
    assert_valid_gltf(out)
    document, _ = read_glb(out)
    assert "KHR_draco_mesh_compression" in document["meshes"][0]["primitives"][0]["extensions"]
    assert "KHR_texture_basisu" in document["textures"][0]["extensions"]
    assert 'src="room.glb"' in (tmp_path / "room.html").read_text()
    usdz = tmp_path / "room.usdz"
    assert main(["texture", str(room), str(ply), "--out", str(usdz), *bake]) == 0
    stage = Usd.Stage.Open(str(usdz))
    (mesh,) = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    extent = np.ptp(np.array(mesh.GetPointsAttr().Get()), axis=0)
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and 2.0 < extent.max() < 8.0  # a room, in metres
    assert main(["texture", str(room), str(ply), "--out", str(tmp_path / "x.usdz"), "--preview", *bake]) == 1
    assert "the preview page shows a .glb" in capsys.readouterr().err
