"""Per-vertex attributes in PLY files: written as float vertex properties beside colours and normals,
read back by name; also from PLYs other tools write (ascii, other property orders)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.mesh_io import read_ply, write_ply


def test_attributes_survive_a_ply_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    vertices = rng.normal(size=(50, 3)).astype(np.float32)
    faces = rng.integers(0, 50, size=(30, 3)).astype(np.int32)
    colors = rng.random((50, 3)).astype(np.float32)
    normals = rng.normal(size=(50, 3)).astype(np.float32)
    attributes = {"observations": rng.integers(0, 9, 50).astype(np.float32),
                  "stereo_confidence": rng.random(50).astype(np.float32),
                  "completed": (rng.random(50) > 0.5).astype(np.float32)}
    write_ply(tmp_path / "m.ply", vertices, faces, normals=normals, colors=colors, attributes=attributes)
    header = (tmp_path / "m.ply").read_bytes().split(b"end_header")[0].decode()
    assert "property float observations" in header and "property float completed" in header
    mesh = read_ply(tmp_path / "m.ply")
    np.testing.assert_array_equal(mesh.vertices, vertices)
    np.testing.assert_array_equal(mesh.faces, faces)
    np.testing.assert_array_equal(mesh.normals, normals)
    np.testing.assert_allclose(mesh.colors, colors, atol=0.5 / 255)
    assert list(mesh.attributes) == list(attributes)
    for name, values in attributes.items():
        assert mesh.attributes[name].dtype == np.float32
        np.testing.assert_array_equal(mesh.attributes[name], values)


def test_a_plain_mesh_has_no_attributes(tmp_path: Path) -> None:
    write_ply(tmp_path / "m.ply", np.eye(3), np.int32([[0, 1, 2]]), colors=np.full((3, 3), 0.5))
    assert read_ply(tmp_path / "m.ply").attributes == {}


def test_ascii_ply_extra_properties_become_attributes(tmp_path: Path) -> None:
    (tmp_path / "a.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float quality\nproperty float y\n"
        "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0.5 0 0 255 0 0 255\n1 1.5 0 0 0 255 0 255\n0 2.5 1 0 0 0 255 255\n3 0 1 2\n")
    mesh = read_ply(tmp_path / "a.ply")
    assert set(mesh.attributes) == {"quality"}  # alpha belongs to the colour
    np.testing.assert_allclose(mesh.attributes["quality"], [0.5, 1.5, 2.5])
    np.testing.assert_allclose(mesh.vertices[:, 0], [0, 1, 0])


@pytest.mark.parametrize("attributes, message", [
    ({"red": np.zeros(3)}, "red"),
    ({"two words": np.zeros(3)}, "two words"),
    ({"observations": np.zeros(4)}, "observations"),
])
def test_bad_attributes_are_refused_by_name(tmp_path: Path, attributes, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        write_ply(tmp_path / "m.ply", np.eye(3), np.int32([[0, 1, 2]]), attributes=attributes)
