"""Capture preparation (engine/poses/prepare.py): one step, the same world through every entry point.

The capture is a COLMAP model of an upright ring of cameras, written in a tilted, shifted world at
0.37 of metres (a COLMAP world has arbitrary orientation and units). Through `engine reconstruct`,
the Blender operators and scripts/vortx_batch.py the cameras must come out in one and the same
world (to 1e-6), and that world must be Z up: the upright ring's mean camera up vector is +Z again.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO
from engine.capture import load_capture
from engine.poses.prepare import NO_POSES, SFM_NEVER, prepare_capture
from fixtures_capture import colmap_image_entry, ring_poses, write_colmap_text, write_photo_folder

W, H = 160, 120
COUNT = 8
CAMERA_HEIGHT = 1.7  # not the default: each entry point must pass the user's value on
UNITS_PER_METRE = 0.37


def _tilt() -> np.ndarray:
    """(4, 4) similarity true world -> COLMAP world: 0.37 scale, 40 deg about a slanted axis, a shift."""
    axis = np.array([1.0, 0.4, 0.2]) / np.linalg.norm([1.0, 0.4, 0.2])
    angle = np.radians(40.0)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rotation = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    tilt = np.eye(4)
    tilt[:3, :3] = UNITS_PER_METRE * rotation
    tilt[:3, 3] = [3.0, -1.0, 0.5]
    return tilt


def _colmap_pose(true_pose: np.ndarray, tilt: np.ndarray) -> np.ndarray:
    """A camera-to-world pose moved by the similarity `tilt` (rotation part kept orthonormal)."""
    pose = tilt @ true_pose
    pose[:3, :3] /= UNITS_PER_METRE
    return pose


@pytest.fixture(scope="module")
def tilted_colmap(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("prepare") / "colmap_capture"
    names = [f"{i:03d}.png" for i in range(COUNT)]
    write_photo_folder(root / "images", COUNT, (W, H), names=names)
    tilt = _tilt()
    poses = [_colmap_pose(p, tilt) for p in ring_poses(COUNT, radius=1.0, height=1.5, target=(0.0, 0.0, 1.2))]
    images = [colmap_image_entry(i + 1, pose, 1, name) for i, (pose, name) in enumerate(zip(poses, names))]
    write_colmap_text(root / "sparse" / "0", [(1, "PINHOLE", W, H, (100.0, 100.0, W / 2, H / 2))], images)
    return root


def _poses(capture) -> np.ndarray:
    return np.stack([f.pose for f in capture.frames if f.pose is not None])


def _assert_z_up_world(poses: np.ndarray, raw: np.ndarray) -> None:
    """Independent of the engine: the upright ring's mean up (-y of each camera) is +Z again, the
    median camera stands CAMERA_HEIGHT above z = 0 (no floor points: SfM units kept), and camera
    spacing is the COLMAP model's (a rigid move, no scale)."""
    up = -poses[:, :3, 1].mean(axis=0)
    np.testing.assert_allclose(up / np.linalg.norm(up), [0.0, 0.0, 1.0], atol=1e-9)
    assert np.median(poses[:, 2, 3]) == pytest.approx(CAMERA_HEIGHT, abs=1e-9)
    spacing = lambda p: np.linalg.norm(p[:, None, :3, 3] - p[None, :, :3, 3], axis=-1)  # noqa: E731
    np.testing.assert_allclose(spacing(poses), spacing(raw), atol=1e-9)


def _cli_world(capture_path: Path, tmp_path: Path, monkeypatch) -> np.ndarray:
    """`python -m engine reconstruct` up to the network: the capture handed to the driver."""
    from engine.recon import cli, driver

    seen = []

    class Stop(Exception):
        pass

    def fake_reconstruct(capture, settings, progress=None, cancel=None, plan=None):
        seen.append(capture)
        raise Stop

    monkeypatch.setattr(driver, "reconstruct", fake_reconstruct)
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    args = parser.parse_args([str(capture_path), "--out", str(tmp_path / "mesh.ply"), "--quiet",
                              "--camera-height", str(CAMERA_HEIGHT)])
    with pytest.raises(Stop):
        cli.run(args)
    return _poses(seen[0])


def _blender_world(blender, scene, capture_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Import Capture through bpy.ops; (the cameras' stored poses, the capture Reconstruct would run on)."""
    import bpy

    scene.vortx.camera_height = CAMERA_HEIGHT
    assert bpy.ops.vortx.import_capture(filepath=str(capture_path)) == {"FINISHED"}
    imported = _poses(blender.vortx_blender.cameras.posed_capture_from_scene(scene))
    for_reconstruct = _poses(blender.vortx_blender.reconstruct.scene_capture(scene))
    return imported, for_reconstruct


INSPECT_CAMERAS = textwrap.dedent(
    """
    import json, sys
    import bpy
    bpy.ops.wm.open_mainfile(filepath=sys.argv[1])
    cameras = sorted((o for o in bpy.data.objects if o.type == "CAMERA" and "vortx_frame" in o), key=lambda o: o["vortx_frame"])
    print("POSES " + json.dumps([list(o["vortx_pose"]) for o in cameras]))
    """
)


def _batch_world(capture_path: Path, tmp_path: Path) -> np.ndarray:
    out = tmp_path / "batch" / "scene.blend"
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "batch-user"))
    tiny = ["--method", "vortx", "--weights", "random", "--voxel-size", "0.16", "--tile-size", "8", "--views", "3", "--image-size", "160",
            "--colour-views", "0", "--max-room-size", "3", "3", "3"]
    run = subprocess.run([sys.executable, str(REPO / "scripts" / "vortx_batch.py"), str(capture_path), "--out", str(out),
                          "--camera-height", str(CAMERA_HEIGHT), *tiny],
                         capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    inspect = subprocess.run([sys.executable, "-c", INSPECT_CAMERAS, str(out)], capture_output=True, text=True, timeout=120,
                             env=dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "inspect-user")))
    line = next((l for l in inspect.stdout.splitlines() if l.startswith("POSES ")), None)
    assert line is not None, inspect.stdout[-2000:] + inspect.stderr[-2000:]
    return np.array(json.loads(line[len("POSES "):]), dtype=np.float64).reshape(-1, 4, 4)


@pytest.mark.slow
def test_same_world_through_cli_blender_and_batch(blender, empty_scene, tilted_colmap: Path, tmp_path: Path,
                                                  monkeypatch) -> None:
    raw = _poses(load_capture(tilted_colmap))
    cli = _cli_world(tilted_colmap, tmp_path, monkeypatch)
    _assert_z_up_world(cli, raw)
    imported, for_reconstruct = _blender_world(blender, empty_scene, tilted_colmap)
    np.testing.assert_allclose(imported, cli, atol=1e-6)
    np.testing.assert_allclose(for_reconstruct, cli, atol=1e-6)
    np.testing.assert_allclose(_batch_world(tilted_colmap, tmp_path), cli, atol=1e-6)


def test_blender_reconstruct_moves_old_tilted_cameras_with_the_world(blender, empty_scene, tilted_colmap: Path) -> None:
    """A scene whose cameras still stand in the raw COLMAP world (saved by an older version): the run
    prepares the capture and moves the cameras with it, so the mesh and the cameras stay together."""
    vb = blender.vortx_blender
    raw = load_capture(tilted_colmap)
    vb.capture.apply_capture(empty_scene, raw, tilted_colmap)
    empty_scene.vortx.camera_height = CAMERA_HEIGHT
    prepared = _poses(vb.reconstruct.scene_capture(empty_scene))
    _assert_z_up_world(prepared, _poses(raw))
    np.testing.assert_allclose(_poses(vb.cameras.posed_capture_from_scene(empty_scene)), prepared, atol=1e-12)
    assert "Z up" in empty_scene.vortx.pose_status


def test_metric_and_unposed_captures_pass_through(tilted_colmap: Path) -> None:
    metric = load_capture(tilted_colmap, metric=True)
    kept = prepare_capture(metric, camera_height=CAMERA_HEIGHT)
    assert kept.scale_source == "metric capture" and not kept.moved() and not kept.ran_sfm
    np.testing.assert_array_equal(_poses(kept.capture), _poses(metric))
    assert kept.pose_status() == f"All {COUNT} posed (colmap), metric"

    unposed = metric.with_frames([f.__class__(f.image_path, f.width, f.height, f.K) for f in metric.frames], metric=False)
    untouched = prepare_capture(unposed, sfm=SFM_NEVER)
    assert untouched.scale_source == NO_POSES and untouched.capture is unposed
    assert untouched.pose_status() == "No poses: run Estimate Poses"


def test_non_metric_capture_reports_what_was_done(tilted_colmap: Path) -> None:
    prepared = prepare_capture(load_capture(tilted_colmap), camera_height=CAMERA_HEIGHT, sfm=SFM_NEVER)
    assert prepared.moved() and prepared.scale_source == "unknown"
    assert prepared.report_lines == [f"poses: {prepared.description}"] and "scale unknown" in prepared.description
    assert any("scale is unknown" in w for w in prepared.warnings)
    assert prepared.pose_status() == f"All {COUNT} posed (colmap), Z up, scale unknown"
    # Preparing a prepared capture changes nothing (what Blender's Reconstruct relies on).
    again = prepare_capture(prepared.capture, camera_height=CAMERA_HEIGHT, sfm=SFM_NEVER)
    assert not again.moved(tolerance=1e-9)


def test_bad_camera_height_is_named(tilted_colmap: Path) -> None:
    from engine.errors import PoseError

    with pytest.raises(PoseError, match="camera height must be positive"):
        prepare_capture(load_capture(tilted_colmap), camera_height=0.0)
