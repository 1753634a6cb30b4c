"""Synthesising rooms end to end: spec -> geometry -> trajectory -> renders -> ScanNet layout + ground truth.

A room folder is written under `<name>.partial/` and renamed when everything is there, so a folder
without the suffix is always complete (`room.json` is written last inside it too). Interrupted runs
resume: complete rooms are skipped, and inside a partial room every frame whose files all exist is
kept (the scene is deterministic, so re-rendering it would give the same pixels).

room.json holds only what the seed and settings determine (no timings), so the same seed and
settings give a byte-identical room.json and pose files; timings go to render_stats.json.

Realism (`SynthOptions.realism`, `synth --realism`): "clean" rooms are rendered as they always
were. "real" rooms are rendered losslessly and then degraded as photos are (engine.data.degrade:
motion blur, rolling focus, exposure and white-balance drift, sensor noise, JPEG 75-90); their
pose/ files carry per-frame errors and pose_true/ the exact poses; depth, mesh_gt.ply and the
TSDF are those of the exact render. `REALISM_PRESETS` adds what else makes a room real: plain
walls, dark and glossy furniture (SURFACE_MIXES "mixed"), dense clutter, and a share of rooms lit
by Cycles. `DEV_ROOM_SETS` are the fixed held-out development sets (`synth --heldout-set NAME`).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from ..jobs import CancelToken, ProgressCallback, check, report
from ..mesh_io import write_ply
from . import scannet_layout as layout
from ..capture.exif import focal_exif_block
from ..tsdf import fuse_ground_truth
from .degrade import DegradationSettings, degrade_photo, frame_rng, perturb_poses, plan_degradations, write_jpeg
from .geometry import room_parts
from .render import RenderSettings, RoomRenderer, bpy_version
from .room import RoomSpec, generate_room
from .room_folders import SYNTH_GT_FILE
from .trajectory import scan_trajectory

FORMAT_VERSION = 1
PARTIAL_SUFFIX = ".partial"
REALISM = ("clean", "real")
# What `--realism NAME` sets besides the photos (explicit options win): a real room has plain walls,
# dark and glossy furniture, more small things, and half of the rooms are lit by Cycles.
REALISM_PRESETS = {
    "clean": {},
    "real": {"surfaces": "mixed", "clutter": "dense", "cycles_share": 0.5},
}
_GOLDEN = 0.6180339887498949
# The fixed held-out development sets (`synth --heldout-set NAME --out DIR`): the same four seeds
# clean (as the held-out rooms have always been rendered) and real; seeds 5001-5004 give two Cycles
# rooms of four. Never used for training.
DEV_ROOM_SETS = ("realistic", "clean")
DEV_ROOM_SEEDS = (5001, 4)  # first seed, number of rooms
DEV_ROOM_FRAMES = 40


@dataclass
class SynthOptions:
    frames: int = 100
    render: RenderSettings = field(default_factory=RenderSettings)
    write_tsdf: bool = True  # ground-truth TSDF (tsdf_gt.npz) fused from the exact float depth
    voxel_size: float = 0.04
    trunc: float = 0.12
    depth_cap: float = 3.0
    surfaces: str = "textured"  # engine.data.room.SURFACE_MIXES
    clutter: str = "normal"  # engine.data.room.CLUTTER_LEVELS
    realism: str = "clean"  # REALISM: "real" degrades the photos and the poses (engine.data.degrade)
    degradation: DegradationSettings = field(default_factory=DegradationSettings)  # "real" only
    cycles_share: float = 0.0  # share of rooms rendered with Cycles whatever `render.renderer` says

    def __post_init__(self) -> None:
        if self.realism not in REALISM:
            raise ValueError(f"realism must be one of {REALISM}, not {self.realism!r}")
        if not 0.0 <= self.cycles_share <= 1.0:
            raise ValueError(f"cycles_share must be within 0..1, not {self.cycles_share}")


def realism_options(realism: str, **options) -> SynthOptions:
    """SynthOptions with `realism` and its preset (REALISM_PRESETS); `options` override the preset."""
    if realism not in REALISM_PRESETS:
        raise ValueError(f"realism must be one of {REALISM}, not {realism!r}")
    return SynthOptions(**{"realism": realism, **REALISM_PRESETS[realism], **options})


def dev_room_set(name: str) -> tuple[int, int, SynthOptions]:
    """(first seed, rooms, options) of a fixed held-out development set (DEV_ROOM_SETS): 40 frames
    of 320 x 240, Workbench (and Cycles for half of the realistic rooms), ground-truth TSDF."""
    if name not in DEV_ROOM_SETS:
        raise ValueError(f"held-out set must be one of {DEV_ROOM_SETS}, not {name!r}")
    render = RenderSettings(renderer="workbench", width=320, height=240)
    options = realism_options("real" if name == "realistic" else "clean", frames=DEV_ROOM_FRAMES, render=render)
    return DEV_ROOM_SEEDS[0], DEV_ROOM_SEEDS[1], options


def room_renderer(seed: int, options: SynthOptions) -> str:
    """The renderer of room `seed`: Cycles for a `cycles_share` of the seeds (the golden-ratio
    sequence of the seed, so any run of consecutive seeds gets close to the exact share), else
    the options' renderer."""
    if options.cycles_share > 0 and (seed * _GOLDEN) % 1.0 < options.cycles_share:
        return "cycles"
    return options.render.renderer


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

    spec = generate_room(seed, options.surfaces, options.clutter)
    poses = room_poses(spec, options.frames)
    settings = replace(options.render, renderer=room_renderer(seed, options))
    K = settings.K
    real = options.realism == "real"
    if real:
        degradations = plan_degradations(poses, settings.width, options.degradation,
                                         np.random.default_rng([seed, 6]))
        given_poses = perturb_poses(poses, options.degradation, seed)
        lens_exif = focal_exif_block(float(K[0, 0]), settings.width, settings.height)
        _write_json_atomic(work / "degradations.json", {"frames": [vars(d) for d in degradations]})
    times: list[float] = []
    t_start = time.perf_counter()
    with RoomRenderer(spec, room_parts(spec), settings, lossless_color=real) as renderer:
        t_built = time.perf_counter()
        for i, pose in enumerate(poses):
            check(cancel)
            if not layout.frame_complete(work, i):
                t0 = time.perf_counter()
                if real:
                    clean = layout.clean_color_path(work, i)
                    depth = renderer.render(pose, clean)
                    photo = degrade_photo(_read_rgb(clean), degradations[i], options.degradation, frame_rng(seed, i))
                    write_jpeg(layout.color_path(work, i), photo, degradations[i].jpeg_quality, lens_exif)
                    layout.write_pose(work, i, pose, folder=layout.TRUE_POSE_DIR)
                else:
                    depth = renderer.render(pose, layout.color_path(work, i))
                times.append(time.perf_counter() - t0)
                layout.write_depth(work, i, depth)
                layout.write_pose(work, i, given_poses[i] if real else pose)
            report(progress, "rendering", frames_done_before + i + 1, total)
        vertices, faces = renderer.scene_mesh()
    write_ply(work / "mesh_gt.ply", vertices, faces)
    layout.write_intrinsics(work, K)

    if options.write_tsdf:
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
    _write_json_atomic(work / "room.json", room_record(spec, options, settings, len(faces)))
    if final.exists():  # a stale incomplete folder without room.json
        shutil.rmtree(final)
    os.replace(work, final)
    return final


def room_record(spec: RoomSpec, options: SynthOptions, settings: RenderSettings, n_triangles: int) -> dict:
    """Everything that defines the room and its files (deterministic: no timings, no paths). A clean
    room's record has no realism keys, so it stays byte-identical to rooms rendered before them."""
    realism = {}
    if options.clutter != "normal":
        realism["clutter"] = options.clutter
    if options.cycles_share > 0:
        realism["cycles_share"] = options.cycles_share
    if options.realism != "clean":
        realism["realism"] = options.realism
        realism["degradation"] = options.degradation.to_json()
    return {
        "format_version": FORMAT_VERSION,
        "seed": spec.seed,
        "dims": [spec.length, spec.width, spec.height],
        "frames": options.frames,
        "intrinsics": np.asarray(settings.K).tolist(),
        "render": settings.to_json(),
        "tsdf": {"voxel_size": options.voxel_size, "trunc": options.trunc, "depth_cap": options.depth_cap}
        if options.write_tsdf else None,
        "mesh_gt_triangles": n_triangles,
        "surfaces": options.surfaces,
        **realism,
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


def _read_rgb(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise OSError(f"could not read the render {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _write_json_atomic(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)
