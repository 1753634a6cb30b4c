"""Synthetic rooms: layout on disk, determinism, depth vs ground-truth mesh, resume, ScanNet round trip.

Renders are tiny (Workbench, 64x48, a few frames) so the whole file stays within seconds.
"""

from __future__ import annotations

import json
import os
import shutil

import cv2
import numpy as np
import pytest

from engine.data import RenderSettings, SynthOptions, generate_room, merge_parts, room_parts, room_poses, synthesize_room
from engine.data.room import wall_frame
from engine.mesh_io import read_ply
from engine.tsdf import TsdfVolume

SEED = 7
FRAMES = 3


def tiny_options(frames: int = FRAMES) -> SynthOptions:
    return SynthOptions(frames=frames, render=RenderSettings(renderer="workbench", width=64, height=48, texture_size=32))


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    return synthesize_room(SEED, tmp_path_factory.mktemp("synth"), tiny_options())


def test_room_folder_has_the_scannet_layout(room):
    stems = [f"{i:06d}" for i in range(FRAMES)]
    assert sorted(p.stem for p in (room / "color").glob("*.jpg")) == stems
    assert sorted(p.stem for p in (room / "pose").glob("*.txt")) == stems
    assert sorted(p.stem for p in (room / "depth").glob("*.png")) == stems
    assert sorted(p.stem for p in (room / "depth_float").glob("*.npy")) == stems
    record = json.loads((room / "room.json").read_text())
    K = np.array(record["intrinsics"])
    for name in ("intrinsic_color.txt", "intrinsic_depth.txt"):
        K4 = np.loadtxt(room / "intrinsic" / name)
        assert K4.shape == (4, 4) and np.allclose(K4[:3, :3], K, atol=1e-6)
    assert K[0, 2] == 32 and K[1, 2] == 24  # principal point at the image centre, pixel (0,0) = [0,1)^2
    color = cv2.imread(str(room / "color" / "000000.jpg"))
    png = cv2.imread(str(room / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
    depth = np.load(room / "depth_float" / "000000.npy")
    assert color.shape == (48, 64, 3) and png.dtype == np.uint16 and depth.shape == (48, 64)
    assert np.array_equal(png, np.round(depth.astype(np.float64) * 1000).astype(np.uint16))
    assert depth.min() > 0.05  # a closed room: every pixel hits a surface
    pose = np.loadtxt(room / "pose" / "000000.txt")
    assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-7) and np.allclose(pose[3], [0, 0, 0, 1])
    assert record["seed"] == SEED and record["frames"] == FRAMES
    vol = TsdfVolume.load(room / "tsdf_gt.npz")
    assert vol.voxel_size == 0.04 and (np.abs(vol.tsdf) < 1).any() and (vol.tsdf == -1).any()


def test_same_seed_gives_identical_room_json_and_poses(room, tmp_path):
    again = synthesize_room(SEED, tmp_path, tiny_options())
    assert (again / "room.json").read_bytes() == (room / "room.json").read_bytes()
    for i in range(FRAMES):
        name = f"pose/{i:06d}.txt"
        assert (again / name).read_bytes() == (room / name).read_bytes()
    other = generate_room(SEED + 1).to_json()
    assert other != json.loads((room / "room.json").read_text())["room"]


def test_ground_truth_mesh_is_the_rendered_geometry(room):
    mesh = read_ply(room / "mesh_gt.ply")
    vertices, faces = merge_parts(room_parts(generate_room(SEED)))
    assert len(mesh.faces) == len(faces)
    # Blender may reorder objects; compare the triangle sets as sorted corner coordinates.
    ours = np.sort(np.round(vertices[faces].reshape(len(faces), -1), 4), axis=0)
    theirs = np.sort(np.round(mesh.vertices[mesh.faces].reshape(len(faces), -1), 4), axis=0)
    assert np.abs(np.sort(ours.ravel()) - np.sort(theirs.ravel())).max() < 1e-3


def ray_mesh_depth(origins: np.ndarray, dirs: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Nearest hit parameter t (R,) of rays origin + t * dir against triangles (T, 3, 3) (Moller-Trumbore)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(dirs[:, None], e2[None])
    det = np.einsum("rtk,tk->rt", p, e1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origins[:, None] - tri[None, :, 0]
    u = np.einsum("rtk,rtk->rt", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("rk,rtk->rt", dirs, q) * inv
    t = np.einsum("tk,rtk->rt", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
    return np.where(hit, t, np.inf).min(axis=1)


def test_rendered_depth_agrees_with_ray_cast_ground_truth(room):
    mesh = read_ply(room / "mesh_gt.ply")
    tri = mesh.vertices[mesh.faces].astype(np.float64)
    K = np.loadtxt(room / "intrinsic" / "intrinsic_depth.txt")[:3, :3]
    errors = []
    for i in range(FRAMES):
        pose = np.loadtxt(room / "pose" / f"{i:06d}.txt")
        depth = np.load(room / "depth_float" / f"{i:06d}.npy")
        rows, cols = np.meshgrid(np.arange(2, 48, 5), np.arange(2, 64, 6), indexing="ij")
        rows, cols = rows.ravel(), cols.ravel()
        # Ray through the pixel centre, scaled so its camera z is 1: the hit parameter is planar depth.
        cam = np.stack([(cols + 0.5 - K[0, 2]) / K[0, 0], (rows + 0.5 - K[1, 2]) / K[1, 1], np.ones(len(rows))], 1)
        dirs = cam @ pose[:3, :3].T
        t = ray_mesh_depth(np.repeat(pose[None, :3, 3], len(rows), 0), dirs, tri)
        errors.append(np.abs(t - depth[rows, cols]))
    errors = np.concatenate(errors)
    assert np.isfinite(errors).all()
    # Pixel centres next to a depth edge can see the other surface; nearly all must agree to 2 mm.
    assert np.median(errors) < 5e-4 and np.mean(errors < 2e-3) > 0.95


def test_resume_renders_only_missing_frames(room, tmp_path):
    copy = tmp_path / room.name
    shutil.copytree(room, copy)
    # Turn it back into an interrupted run: no room.json, frame 1 unfinished (its pose is written last).
    partial = copy.with_name(copy.name + ".partial")
    os.replace(copy, partial)
    (partial / "room.json").unlink()
    (partial / "pose" / "000001.txt").unlink()
    before = (partial / "color" / "000000.jpg").stat().st_mtime_ns
    out = synthesize_room(SEED, tmp_path, tiny_options())
    assert out == copy and not partial.exists()
    assert json.loads((out / "render_stats.json").read_text())["frames_rendered"] == 1
    assert (out / "color" / "000000.jpg").stat().st_mtime_ns == before
    assert (out / "pose" / "000001.txt").read_bytes() == (room / "pose" / "000001.txt").read_bytes()
    # A complete room is skipped outright.
    stamp = (out / "room.json").stat().st_mtime_ns
    synthesize_room(SEED, tmp_path, tiny_options())
    assert (out / "room.json").stat().st_mtime_ns == stamp


def test_scannet_loader_reads_the_room_back(room):
    from engine.capture import load_capture

    capture = load_capture(room)
    assert capture.format == "scannet" and capture.metric and len(capture.frames) == FRAMES
    K = np.loadtxt(room / "intrinsic" / "intrinsic_color.txt")[:3, :3]
    for i, frame in enumerate(capture.frames):
        assert frame.image_path.name == f"{i:06d}.jpg" and (frame.width, frame.height) == (64, 48)
        assert np.allclose(frame.K, K) and frame.depth_path == room / "depth" / f"{i:06d}.png"
        assert np.allclose(frame.pose, np.loadtxt(room / "pose" / f"{i:06d}.txt"), atol=1e-9)


@pytest.mark.parametrize("seed", range(12))
def test_rooms_and_walks_stay_within_the_rules(seed):
    spec = generate_room(seed)
    assert 3 <= spec.length <= 8 and 3 <= spec.width <= 8 and 2.4 <= spec.height <= 3.2
    assert spec.furniture and any(o.kind == "door" for o in spec.openings)
    for o in spec.openings:
        _, _, span = wall_frame(o.wall, spec.length, spec.width)
        assert 0 < o.u0 < o.u1 < span and 0 <= o.z0 < o.z1 < spec.height
    poses = room_poses(spec, 60)
    centres = poses[:, :3, 3]
    assert np.all((centres[:, 2] >= 1.2) & (centres[:, 2] <= 1.8))
    assert np.all((centres[:, :2] > 0.2) & (centres[:, :2] < [spec.length - 0.2, spec.width - 0.2]))
    for piece in spec.furniture:  # never inside a piece of furniture
        c, s = np.cos(piece.yaw), np.sin(piece.yaw)
        rel = centres[:, :2] - piece.center
        local = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], 1)
        assert np.all(np.any(np.abs(local) > np.array(piece.footprint) / 2 + 0.2, axis=1))
    forward = poses[:, :3, 2]
    turn = np.degrees(np.arccos(np.clip((forward[1:] * forward[:-1]).sum(1), -1, 1)))
    assert turn.max() < 20  # neighbours overlap well
    assert np.linalg.norm(np.diff(centres, axis=0), axis=1).max() < 0.6
    # Image x stays roughly level (hand-held roll only).
    assert np.all(np.abs(poses[:, 2, 0]) < np.sin(np.radians(12)))
