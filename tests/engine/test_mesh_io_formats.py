"""PLY / OBJ reading and writing (engine/mesh_io.py)."""

from __future__ import annotations

import numpy as np

from engine.mesh_io import read_ply, write_obj, write_ply


def test_binary_ply_round_trip_with_normals_and_colours(tmp_path):
    rng = np.random.default_rng(0)
    v = rng.random((50, 3)).astype(np.float32)
    f = rng.integers(0, 50, (80, 3)).astype(np.int32)
    n = rng.random((50, 3)).astype(np.float32)
    c = rng.random((50, 3)).astype(np.float32)
    write_ply(tmp_path / "m.ply", v, f, normals=n, colors=c)
    m = read_ply(tmp_path / "m.ply")
    assert np.array_equal(m.vertices, v) and np.array_equal(m.faces, f) and np.array_equal(m.normals, n)
    assert np.abs(m.colors - c).max() <= 0.5 / 255 + 1e-6
    write_ply(tmp_path / "p.ply", v)  # point cloud
    p = read_ply(tmp_path / "p.ply")
    assert p.faces.shape == (0, 3) and p.normals is None and p.colors is None


def test_ascii_ply_with_quad_and_mixed_polygons(tmp_path):
    text = """ply
format ascii 1.0
comment a quad and a triangle
element vertex 5
property float x
property float y
property float z
property uchar red
property uchar green
property uchar blue
element face 2
property list uchar int vertex_indices
end_header
0 0 0 255 0 0
1 0 0 0 255 0
1 1 0 0 0 255
0 1 0 255 255 255
2 2 2 0 0 0
4 0 1 2 3
3 1 4 2
"""
    (tmp_path / "a.ply").write_text(text)
    m = read_ply(tmp_path / "a.ply")
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2]]
    assert m.colors[0].tolist() == [1, 0, 0] and m.vertices[4].tolist() == [2, 2, 2]


def test_big_endian_binary_faces(tmp_path):
    header = ("ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
              "property double z\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n")
    body = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], ">f8").tobytes() + bytes([3]) + np.array([2, 1, 0], ">u4").tobytes()
    (tmp_path / "b.ply").write_bytes(header.encode() + body)
    m = read_ply(tmp_path / "b.ply")
    assert m.faces.tolist() == [[2, 1, 0]] and m.vertices[1].tolist() == [1, 0, 0]


def test_obj_writer(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    write_obj(tmp_path / "m.obj", v, [[0, 1, 2]], normals=[[0, 0, 1]] * 3, colors=[[1, 0.5, 0]] * 3)
    lines = (tmp_path / "m.obj").read_text().splitlines()
    assert "v 1.000000 0.000000 0.000000 1.0000 0.5020 0.0000" in lines
    assert "f 1//1 2//2 3//3" in lines and sum(l.startswith("vn ") for l in lines) == 3
