"""`python -m engine reconstruct` from each capture layout the loaders read, to a mesh.

The same synthetic posed room is written as a ScanNet export, a COLMAP text model and a
transforms.json; the bundled demo photos (no poses) go through structure from motion first.
Random weights and tiny settings: this checks the plumbing from each layout, not quality.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from fixtures_capture import colmap_image_entry, write_colmap_text, write_transforms_json

from engine.__main__ import main
from engine.capture import load_capture
from engine.mesh_io import read_ply
from engine.recon.synthetic import make_synthetic_capture

TINY = ["--method", "vortx", "--weights", "random", "--voxel-size", "0.16", "--tile-size", "8", "--views", "3", "--image-size", "160",
        "--colour-views", "2", "--max-room-size", "2", "2", "2", "--quiet"]
REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """The synthetic room as a ScanNet export, plus its capture (metric poses, shared K)."""
    path = tmp_path_factory.mktemp("scannet")
    capture = make_synthetic_capture(path, room_size=(3.0, 3.0, 2.5), frames=8, image_size=(160, 120))
    return path, capture


def as_colmap(room, root: Path) -> Path:
    _, capture = room
    shutil.copytree(capture.frames[0].image_path.parent, root / "images")
    K = capture.frames[0].K
    cameras = [(1, "PINHOLE", 160, 120, [K[0, 0], K[1, 1], K[0, 2], K[1, 2]])]
    images = [colmap_image_entry(i + 1, f.pose, 1, f.image_path.name) for i, f in enumerate(capture.frames)]
    write_colmap_text(root / "sparse" / "0", cameras, images)
    return root


def as_transforms(room, root: Path) -> Path:
    _, capture = room
    shutil.copytree(capture.frames[0].image_path.parent, root / "images")
    K = capture.frames[0].K
    frames = [(f"images/{f.image_path.name}", f.pose) for f in capture.frames]
    write_transforms_json(root / "transforms.json", frames, fl_x=K[0, 0], fl_y=K[1, 1], cx=K[0, 2], cy=K[1, 2],
                          w=160, h=120)
    return root


@pytest.mark.parametrize("layout", ["scannet", "colmap", "transforms"])
def test_each_posed_layout_reconstructs_to_a_mesh(room, layout, tmp_path):
    source = {"scannet": lambda: room[0], "colmap": lambda: as_colmap(room, tmp_path / "c"),
              "transforms": lambda: as_transforms(room, tmp_path / "t")}[layout]()
    assert load_capture(source).format == layout
    out = tmp_path / "mesh.ply"
    assert main(["reconstruct", str(source), "--out", str(out), *TINY]) == 0
    mesh = read_ply(out)
    sidecar = json.loads(out.with_suffix(".json").read_text())
    assert sidecar["capture_format"] == layout
    assert len(mesh.faces) == sidecar["mesh"]["faces"] > 0
    # Whatever the layout, the mesh sits around the cameras (within the 2 m clipped room).
    centres = np.array([f.pose[:3, 3] for f in room[1].frames])
    assert np.abs(np.median(mesh.vertices, axis=0)[:2] - np.median(centres, axis=0)[:2]).max() < 1.5


def test_photos_without_poses_get_structure_from_motion_first(tmp_path, capfd):
    photos = REPO / "samples" / "demo_room" / "images"
    out = tmp_path / "room.ply"
    assert main(["reconstruct", str(photos), "--out", str(out), *TINY]) == 0
    err = capfd.readouterr().err
    assert "registered 36 of 36 photos" in err  # the SfM report is shown to the user
    assert len(read_ply(out).faces) > 0
