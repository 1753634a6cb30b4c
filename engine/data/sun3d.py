"""The SUN3D study-room sample of the 3DMatch toolbox as a development room with ground truth.

Source: andyzeng/3dmatch-toolbox, `data/sample/depth-fusion-demo` at commit 4b4a3687 (later commits
replaced those frames): `camera-intrinsics.txt` (3x3), and two folders `fragment-*-rgbd-frames/` of
`frame-NNNNNN.color.png` (640 x 480 RGB from an Xtion), `frame-NNNNNN.depth.png` (uint16 millimetres,
registered to the colour camera) and `frame-NNNNNN.pose.txt` (camera-to-world 4x4, OpenCV axes,
metres, one world for both fragments, y up).

It becomes a room folder in the ScanNet layout (`scannet_layout.py`) that `engine.data.room_folders`
finds and `load_capture` reads: the colour photos and their poses (turned so that up is +Z, the
product's world) are the capture; the sensor depth goes beside them as `depth/` for the ground truth
only (the reconstruction methods never read a frame's depth). The ground truth is the sensor depth
fused by the project's own TSDF fusion: `tsdf_gt_04.npz` at 4 cm (the evaluation's observed-space
trim) and `mesh_gt.ply`, marching cubes of a 2 cm fusion.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from . import scannet_layout as layout
from ..errors import VortxError
from ..geometry.cameras import rotation_taking
from ..jobs import ProgressCallback, report
from ..mesh_io import write_ply
from ..recon.mesh import extract_mesh
from ..tsdf.integration import fuse_ground_truth

SOURCE_COMMIT = "4b4a3687e5baca3098ab1791b0b30948650a0667"
MAX_SENSOR_DEPTH = 4.0  # metres: an Xtion's depth beyond this is too noisy to be a truth
GT_MESH_VOXEL = 0.02  # metres: the truth mesh's fusion voxel (the sensor's noise is ~1 cm at 2 m)


def find_frames(source: Path) -> list[Path]:
    """The frames' common path stems (`.../frame-000935`), fragment by fragment, in order."""
    stems = sorted(p.with_name(p.name[: -len(".color.png")]) for p in source.glob("fragment-*-rgbd-frames/frame-*.color.png"))
    if not stems:
        raise VortxError(f"{source} has no fragment-*-rgbd-frames/frame-*.color.png: give the folder "
                         f"data/sample/depth-fusion-demo of the 3DMatch toolbox at commit {SOURCE_COMMIT[:8]}")
    for stem in stems:
        for suffix in (".depth.png", ".pose.txt"):
            if not stem.with_name(stem.name + suffix).is_file():
                raise VortxError(f"{stem.name}{suffix} is missing in {stem.parent}: the SUN3D sample is incomplete")
    return stems


# The sample's world keeps gravity on +y: its floor's normal (the fused sensor surface's up-facing
# faces) is 0.7 deg from +y. The cameras' mean up is not gravity: the Xtion was held looking down, and
# up from it left the room 19 deg tilted (the converter's first version).
SUN3D_UP = np.array([0.0, 1.0, 0.0])


def z_up_rotation() -> np.ndarray:
    """(3, 3) rotation that turns the sample's up (SUN3D_UP) onto +Z, the smallest that does it."""
    return rotation_taking(SUN3D_UP, np.array([0.0, 0.0, 1.0]))


def convert_sun3d(source: Path, out: Path, progress: Optional[ProgressCallback] = None) -> dict:
    """Write the room folder `out` from the sample folder `source`; returns a summary dict."""

    source, out = Path(source), Path(out)
    if out.exists() and any(out.iterdir()):
        raise VortxError(f"{out} exists and is not empty: choose a new folder for the SUN3D room")
    stems = find_frames(source)
    intrinsics = source / "camera-intrinsics.txt"
    if not intrinsics.is_file():
        raise VortxError(f"{intrinsics} is missing: the SUN3D sample is incomplete")
    K = np.loadtxt(intrinsics).reshape(3, 3)
    poses = np.stack([np.loadtxt(s.with_name(s.name + ".pose.txt")).reshape(4, 4) for s in stems])
    world = np.eye(4)
    world[:3, :3] = z_up_rotation()
    poses = world @ poses

    depths = []
    for i, stem in enumerate(stems):
        report(progress, "SUN3D frames", i, len(stems))
        (out / layout.COLOR_DIR).mkdir(parents=True, exist_ok=True)
        shutil.copyfile(stem.with_name(stem.name + ".color.png"), out / layout.COLOR_DIR / f"{layout.frame_stem(i)}.png")
        (out / layout.POSE_DIR).mkdir(parents=True, exist_ok=True)
        np.savetxt(layout.pose_path(out, i), poses[i], fmt="%.9f")
        raw = cv2.imread(str(stem.with_name(stem.name + ".depth.png")), cv2.IMREAD_UNCHANGED)
        if raw is None or raw.dtype != np.uint16:
            raise VortxError(f"{stem.name}.depth.png is not a 16-bit PNG depth map")
        depth = raw.astype(np.float32) / 1000.0
        depth[depth > MAX_SENSOR_DEPTH] = 0.0
        layout.write_depth(out, i, depth)
        depths.append(depth)
    layout.write_intrinsics(out, K)

    report(progress, "SUN3D ground truth", 0, 2)
    volume = fuse_ground_truth(depths, K, poses, voxel_size=0.04, trunc=0.12, depth_cap=MAX_SENSOR_DEPTH)
    volume.save(out / "tsdf_gt_04.npz")
    fine = fuse_ground_truth(depths, K, poses, voxel_size=GT_MESH_VOXEL, trunc=3 * GT_MESH_VOXEL,
                             depth_cap=MAX_SENSOR_DEPTH)
    observed = fine.weight > 0
    mesh = extract_mesh(np.argwhere(observed), fine.tsdf[observed], fine.origin, GT_MESH_VOXEL)
    write_ply(out / "mesh_gt.ply", mesh.vertices, mesh.faces)
    report(progress, "SUN3D ground truth", 2, 2)
    return {"frames": len(stems), "mesh_vertices": int(len(mesh.vertices)), "mesh_faces": int(len(mesh.faces)),
            "up_rotation_deg": float(np.degrees(np.arccos(np.clip((np.trace(world[:3, :3]) - 1) / 2, -1, 1))))}
