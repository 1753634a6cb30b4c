"""Rendered room folders on disk: finding them, and their 4 cm ground-truth TSDF.

A room folder is written by `python -m engine synth` in the ScanNet layout (scannet_layout.py) with
`mesh_gt. py` and, unless rendered with --no-tsdf, `tsdf_gt.npz` fused from the exact float depth.
Rooms without it get `tsdf_gt_04.npz`, fused once from the stored depth maps by `precompute_room`.
Training (engine.train), held-out evaluation and `python -m engine eval` all read the file that
`gt_path` names, so they agree on which ground truth a room has.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..capture import load_capture, load_depth
from ..capture.geometry import parse_pose
from ..errors import VortxError
from ..geometry.cameras import scale_intrinsics
from ..tsdf.integration import fuse_ground_truth
from .scannet_layout import TRUE_POSE_DIR

GT_FILE = "tsdf_gt_04.npz"  # written by precompute_room when the renderer did not write one
SYNTH_GT_FILE = "tsdf_gt.npz"  # written by `python -m engine synth` (fused from exact float depth)


def is_room_dir(path: Path) -> bool:
    """A finished room folder (a renderer's unfinished `*.partial` folder is not one)."""
    if path.name.endswith(".partial"):
        return False
    return (path / "mesh_gt.ply").is_file() or (path / "pose").is_dir()


def find_rooms(paths: Sequence[str | Path]) -> list[Path]:
    """Room folders named directly, or found one level below the given folders; sorted, unique."""
    rooms: list[Path] = []
    for p in map(Path, paths):
        if is_room_dir(p):
            rooms.append(p)
        elif p.is_dir():
            rooms.extend(sorted(c for c in p.iterdir() if c.is_dir() and is_room_dir(c)))
        else:
            raise VortxError(f"training data {p} is not a folder; render rooms with `python -m engine synth`")
    return sorted(dict.fromkeys(rooms))


def gt_path(room: Path) -> Optional[Path]:
    """The room's 4 cm ground-truth TSDF file: the renderer's `tsdf_gt.npz`, else ours, else None."""
    for name in (SYNTH_GT_FILE, GT_FILE):
        if (Path(room) / name).is_file():
            return Path(room) / name
    return None


def with_true_poses(capture):
    """The room's capture with every frame at the pose it was rendered from: a "real" room
    (`synth --realism real`) gives methods poses with errors in pose/ and keeps the exact ones in
    pose_true/; scoring against the true depth maps must use those. Other rooms come back as they are."""
    true_dir = Path(capture.root) / TRUE_POSE_DIR
    if not true_dir.is_dir():
        return capture
    frames = []
    for frame in capture.frames:
        path = true_dir / f"{Path(frame.image_path).stem}.txt"
        if not path.is_file():
            raise VortxError(f"{path} is missing: the room's true poses are incomplete; render the room again "
                             f"with `python -m engine synth`")
        frames.append(replace(frame, pose=parse_pose(np.loadtxt(path))))
    return capture.with_frames(frames)


class _LazyDepths:
    """Sequence of depth maps read on access (fusion reads one frame at a time)."""

    def __init__(self, paths):
        self.paths = list(paths)

    def __len__(self):
        return len(self.paths)

    def __getitem__(self, i):
        return load_depth(self.paths[i])


def precompute_room(room: Path, force: bool = False, progress=None) -> Path:
    """The room's ground-truth TSDF file; when it has none (or `force`), fuse it at 4 cm
    (engine.tsdf.fuse_ground_truth: 12 cm truncation, 3 m depth cap, frustum bounds) and save it as
    `tsdf_gt_04.npz` (TsdfVolume format) beside it."""
    out = Path(room) / GT_FILE
    if not force:
        existing = gt_path(room)
        if existing is not None:
            return existing
    capture = load_capture(room)
    frames = [f for f in capture.frames if f.pose is not None and f.depth_path is not None]
    if not frames:
        raise VortxError(f"room {room}: no frame has both a pose and a depth map")
    depths = _LazyDepths([f.depth_path for f in frames])
    d0 = depths[0]
    # K may refer to the colour image; fusion needs it in depth-map pixels
    Ks = [scale_intrinsics(f.K, (f.width, f.height), (d0.shape[1], d0.shape[0])) for f in frames]
    volume = fuse_ground_truth(depths, np.stack(Ks), np.stack([f.pose for f in frames]), progress=progress)
    tmp = out.with_name(out.stem + ".tmp.npz")
    volume.save(tmp)
    tmp.replace(out)
    return out
