"""Synthesising rooms end to end: spec -> geometry -> trajectory -> renders -> ScanNet layout + ground truth.

A room folder is written under `<name>.partial/` and renamed when everything is there, so a folder
without the suffix is always complete (`room.json` is written last inside it too). Interrupted runs
resume: complete rooms are skipped, and inside a partial room every frame whose files all exist is
kept (the scene is deterministic, so re-rendering it would give the same pixels).

room.json holds only what the seed and settings determine (no timings), so the same seed and
settings give a byte-identical room.json and pose files; timings go to render_stats.json.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from ..jobs import CancelToken, ProgressCallback, check, report
from ..mesh_io import write_ply
from . import scannet_layout as layout
from .geometry import room_parts
from .render import RenderSettings, RoomRenderer, bpy_version
from .room import RoomSpec, generate_room
from .trajectory import scan_trajectory

FORMAT_VERSION = 1
PARTIAL_SUFFIX = ".partial"


@dataclass
class SynthOptions:
    frames: int = 100
    render: RenderSettings = field(default_factory=RenderSettings)
    write_tsdf: bool = True  # ground-truth TSDF (tsdf_gt.npz) fused from the exact float depth
    voxel_size: float = 0.04
    trunc: float = 0.12
    depth_cap: float = 3.0
    surfaces: str = "textured"  # engine.data.room.SURFACE_MIXES


def room_name(seed: int) -> str:
    return f"room_{seed:05d}"


def room_is_complete(folder: Path) -> bool:
    return (folder / "room.json").is_file()


def room_poses(spec: RoomSpec, frames: int) -> np.ndarray:
    """(frames, 4, 4) camera-to-world poses of the room's scan; their own random stream, so the
    number of frames never changes the room itself."""
    return scan_trajectory(spec, frames, np.random.default_rng([spec.seed, 1]))


def synthesize_room(
    seed: int,
    out_root: Path,
    options: SynthOptions,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    frames_done_before: int = 0,
    frames_total: Optional[int] = None,
) -> Path:
    """Render room `seed` into `out_root/room_<seed>/`. Returns the folder; skips it if complete.

    progress is reported as ("rendering", frames done, frames_total) so several rooms share one bar.
    """
    final = Path(out_root) / room_name(seed)
    total = frames_total or options.frames
    if room_is_complete(final):
        report(progress, "rendering", frames_done_before + options.frames, total)
        return final
    work = final.with_name(final.name + PARTIAL_SUFFIX)
    work.mkdir(parents=True, exist_ok=True)

    spec = generate_room(seed, options.surfaces)
    poses = room_poses(spec, options.frames)
    settings = options.render
    K = settings.K
    times: list[float] = []
    t_start = time.perf_counter()
    with RoomRenderer(spec, room_parts(spec), settings) as renderer:
        t_built = time.perf_counter()
        for i, pose in enumerate(poses):
            check(cancel)
            if not layout.frame_complete(work, i):
                t0 = time.perf_counter()
                depth = renderer.render(pose, layout.color_path(work, i))
                times.append(time.perf_counter() - t0)
                layout.write_depth(work, i, depth)
                layout.write_pose(work, i, pose)
            report(progress, "rendering", frames_done_before + i + 1, total)
        vertices, faces = renderer.scene_mesh()
    write_ply(work / "mesh_gt.ply", vertices, faces)
    layout.write_intrinsics(work, K)

    if options.write_tsdf:
        from ..tsdf import fuse_ground_truth
        from .room_folders import SYNTH_GT_FILE

        depths = _LazyDepths(work, options.frames)
        volume = fuse_ground_truth(depths, K, poses, options.voxel_size, options.trunc, options.depth_cap,
                                   cancel=cancel)
        volume.save(work / SYNTH_GT_FILE)

    stats = {
        "build_s": round(t_built - t_start, 3),
        "frames_rendered": len(times),
        "render_s_per_frame_mean": round(float(np.mean(times)), 3) if times else None,
        "render_s_per_frame_first": round(times[0], 3) if times else None,
        "total_s": round(time.perf_counter() - t_start, 3),
    }
    (work / "render_stats.json").write_text(json.dumps(stats, indent=2) + "\n")
    _write_json_atomic(work / "room.json", room_record(spec, options, K, len(faces)))
    if final.exists():  # a stale incomplete folder without room.json
        shutil.rmtree(final)
    os.replace(work, final)
    return final


def room_record(spec: RoomSpec, options: SynthOptions, K: np.ndarray, n_triangles: int) -> dict:
    """Everything that defines the room and its files (deterministic: no timings, no paths)."""
    return {
        "format_version": FORMAT_VERSION,
        "seed": spec.seed,
        "dims": [spec.length, spec.width, spec.height],
        "frames": options.frames,
        "intrinsics": np.asarray(K).tolist(),
        "render": options.render.to_json(),
        "tsdf": {"voxel_size": options.voxel_size, "trunc": options.trunc, "depth_cap": options.depth_cap}
        if options.write_tsdf else None,
        "mesh_gt_triangles": n_triangles,
        "surfaces": options.surfaces,
        "blender": bpy_version(),
        "conventions": "metres; world Z up; pose = camera-to-world, OpenCV camera axes; K pixel (0,0) "
                       "covers [0,1)^2; depth PNG uint16 mm; depth_float planar metres; 0 = no depth",
        "room": spec.to_json(),
    }


def synthesize_rooms(
    n_rooms: int,
    out_root: Path,
    options: SynthOptions,
    first_seed: int = 0,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
) -> list[Path]:
    """Rooms with seeds first_seed .. first_seed + n_rooms - 1 (complete ones are skipped)."""
    folders = []
    total = n_rooms * options.frames
    for k in range(n_rooms):
        check(cancel)
        folders.append(synthesize_room(first_seed + k, out_root, options, progress, cancel,
                                       frames_done_before=k * options.frames, frames_total=total))
    return folders


class _LazyDepths:
    """Sequence view of a room's float depth maps, read one at a time (TSDF fusion streams them)."""

    def __init__(self, root: Path, n: int) -> None:
        self.root, self.n = root, n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> np.ndarray:
        return layout.read_depth_float(self.root, i)


def _write_json_atomic(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)
