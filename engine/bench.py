"""`python -m engine bench [--quick] [--out bench.json]`: how fast and how big the pipeline is here.

Runs the full VoRTX reconstruction (official network widths, seeded random weights, 4 cm voxels,
320 x 240 images) on procedurally generated posed captures of box rooms, so no Blender and no data
are needed; the numbers measure speed and memory, not quality. Reports end-to-end keyframes per
second, wall and CPU seconds per stage, voxels per level and peak RSS; scaling with the views per
tile (N = 20 / 40 / 60) and with the room size; the sparse 3D convolution against a dense Conv3d on
the same volume (engine.sparse.bench); and the memory model of engine.recon.memory_estimate checked
against the measured runs, then applied to a 10 x 10 x 3 m room at N = 60.

The classical stereo method (the default) runs on the same captures and regions with its default
settings, its stages reported separately (stereo depth, TSDF fusion, mesh, colour, evidence), and is
checked against the cost budget of issue 11: within 2x the CPU time of VoRTX on the same capture
(at the most views per tile measured there) and within VoRTX's peak memory + 1 GiB.

The learned method with stereo evidence (an untrained network of the training recipe's widths, or
`--evidence-weights`) runs on the same capture as stereo fusion, its stages reported separately: the
stereo stages it shares with the classical method, and the network (2D features, view fusion, 3D CNN).
It is checked against issue 19's budget: within 1.5x the classical method's CPU time per keyframe and
within its peak memory + 1 GiB.

The texture bake (VR preset: engine.texture.vr.textured_result) runs on the first stereo mesh with
all its capture's photos, at each of TEXTURE_SIZES (--quick: the smallest): atlas, texels, bake
seconds and the bake's own peak RSS.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Optional

import numpy
import torch

from .capture import load_capture
from .eval.real_rooms import DEFAULT_DATA, run_suite
from .poses.sfm import FEATURES, SfmOptions
from .eval.stereo_depth import KEYS as DEPTH_KEYS, compare_depth, true_depth_at
from .poses.prepare import SFM_NEVER, prepare_capture
from .poses.refine import refine_poses
from .recon.plan import plan_reconstruction, posed_frames
from .recon.stereo_fusion import stereo_options
from .stereo import stage_clock
from .stereo.depth_maps import estimate_depth_maps
from .stereo.options import MATCHER_PATCHMATCH
from .model.config import StereoEvidenceConfig, VortxConfig
from .model.vortx import VortxNet
from .recon.driver import reconstruct, run_reconstruction
from .recon.memory import PeakMemory
from .recon.memory_estimate import (box_room_surface_area, coarse_voxels, estimate_memory, keep_fraction_voxels,
                                    surface_band_voxels)
from .recon.network import load_network
from .recon.settings import ReconSettings
from .recon.synthetic import make_synthetic_capture
from .sparse.bench import bench_sparse_vs_dense
from .stereo.options import STEREO_MATCHERS
from .texture.options import TextureOptions
from .texture.views import views_from_capture
from .texture.vr import textured_result

MB = 2**20
STEREO_CPU_BUDGET = 2.0  # stereo fusion may take this many times VoRTX's CPU seconds on the same capture
STEREO_MEMORY_BUDGET = 2**30  # ... and this many bytes more peak RSS
STEREO_STAGES = ("stereo depth", "TSDF fusion", "mesh", "colour", "evidence")
EVIDENCE_CPU_BUDGET = 1.5  # the learned method may take this many times stereo fusion's CPU seconds per keyframe
EVIDENCE_MEMORY_BUDGET = 2**30  # ... and this many bytes more peak RSS
# The widths of the evidence model's training recipe (configs/train_evidence.json).
EVIDENCE_WIDTHS = {"feature_channels": (32, 24, 16), "unet_base_widths": (16, 16, 8), "image_long_side": 128,
                   "sparse_norm_statistics": "scene"}


@dataclass(frozen=True)
class Case:
    name: str
    region: tuple[float, float, float]  # metres reconstructed: the scene bounds are clipped to this
    views: int  # N, keyframes per tile
    frames: int  # generated frames; all are keyframes (steps of >= 0.118 m on the camera circle)


FULL_CASES = (
    Case("N=20, 2 m region", (2.0, 2.0, 2.5), 20, 64),
    Case("N=40, 2 m region", (2.0, 2.0, 2.5), 40, 64),
    Case("N=60, 2 m region", (2.0, 2.0, 2.5), 60, 64),
    Case("N=20, 1.5 m region", (1.5, 1.5, 2.5), 20, 32),
    Case("N=20, 3 m region", (3.0, 3.0, 2.5), 20, 32),
)
QUICK_CASES = (Case("N=20, 1.5 m region", (1.5, 1.5, 2.5), 20, 24),)
# Every capture is the same 4 x 4 x 2.5 m box room seen from a 1.2 m circle, looking in across the
# middle (20 deg off the centre), so every camera sees the reconstructed region around the centre;
# 64 frames on the circle are 0.118 m apart, so all are keyframes (> 0.1 m) and a tile can have 60 views.
RENDER_ROOM = (4.0, 4.0, 2.5)
CAMERA_RADIUS = 1.2
CAMERA_OUTWARD_DEG = -70.0
FULL_SPARSE = ({"grid": (96, 96, 48), "channels": 32}, {"grid": (96, 96, 48), "channels": 16, "occupancy": 0.1})
QUICK_SPARSE = ({"grid": (48, 48, 24), "channels": 16, "repeats": 1},)
IMAGE_SIZE = (320, 240)
PROJECTED_ROOM = (10.0, 10.0, 3.0)
PROJECTED_KEYFRAMES = 500  # a careful walk around a 10 x 10 m room at 0.1 m / 15 deg spacing
PROJECTED_IMAGE = (640, 480)
TEXTURE_SIZES = (2048, 4096)
QUICK_TEXTURE_SIZES = (2048,)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="one small run and a small sparse-conv check (about a "
                        "minute); with --real, the rooms marked quick, their default run only")
    parser.add_argument("--real", type=Path, nargs="?", const=DEFAULT_DATA, default=None, metavar="DATA_DIR",
                        help="the real-room suite instead (engine/eval/real_rooms.py): every real capture with truth "
                             "under DATA_DIR (default %(const)s), every default, scored, beside docs/real_rooms.json")
    parser.add_argument("--rooms", nargs="+", default=None, metavar="NAME", help="with --real: only these rooms")
    parser.add_argument("--repeat", type=int, default=1,
                        help="with --real: run each room this many times and record the spread between the runs")
    parser.add_argument("--features", choices=FEATURES, default=SfmOptions.features,
                        help="with --real: pose the photos alone with these features; other than the default, only the "
                             "photos-alone runs, recorded as 'photos alone (FEATURES)' (default %(default)s)")
    parser.add_argument("--out", type=Path, default=None, help="also write the results as JSON here")
    parser.add_argument("--device", default="cpu", help="cpu or cuda (default %(default)s)")
    parser.add_argument("--evidence-weights", type=Path, default=None,
                        help="weights of the learned method with stereo evidence (default: untrained, the recipe's widths)")
    parser.add_argument("--patchmatch-profile", type=Path, default=None, metavar="ROOM",
                        help="instead of the benchmark: CPU seconds per keyframe of each PatchMatch stage (one thread) "
                             "and the depth maps against the room's true depth, on a few consecutive keyframes of ROOM "
                             "(a room folder with true depth, its poses as given)")
    parser.add_argument("--refine-profile", type=Path, default=None, metavar="CAPTURE",
                        help="instead of the benchmark: the pose refinement of CAPTURE's given poses (a posed capture, e.g. "
                             "the SUN3D room), seconds per stage, frames adjusted, errors and stretch scales")
    parser.add_argument("--profile-sizes", type=int, nargs="+", default=[160, 320], help="stereo long sides profiled")
    parser.add_argument("--profile-references", type=int, default=5, help="consecutive keyframes profiled")
    parser.add_argument("--profile-first", type=int, default=0, help="the first keyframe profiled")
    parser.add_argument("--profile-set", nargs="*", default=[], metavar="FIELD=VALUE",
                        help="StereoOptions fields changed for the profile (e.g. coarse_iterations=2)")


def machine_info() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    info: dict[str, Any] = {
        "cpu": cpu,
        "logical_cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "numpy": numpy.__version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
    }
    if hasattr(os, "getloadavg"):
        info["load_average_at_start"] = [round(v, 2) for v in os.getloadavg()]
    return info


def bench_capture(case: Case, workdir: Path) -> Any:
    """The generated capture of `case` (made once per frame count in `workdir`), loaded."""

    capture_dir = workdir / f"room_{case.frames}_frames"
    if not capture_dir.exists():
        make_synthetic_capture(capture_dir, room_size=RENDER_ROOM, frames=case.frames, image_size=IMAGE_SIZE,
                               radius=CAMERA_RADIUS, outward_deg=CAMERA_OUTWARD_DEG)
    return load_capture(capture_dir)


def run_case(case: Case, device: str, workdir: Path) -> dict[str, Any]:
    """One VoRTX run (random weights of the official widths) of `case`."""

    capture = bench_capture(case, workdir)
    settings = ReconSettings(method="vortx", weights="random", views=case.views, device=device,
                             image_long_side=max(IMAGE_SIZE), max_room_size=case.region)
    result = reconstruct(capture, settings)
    stats = result.stats
    levels = stats["levels"]
    memory = stats["memory"]
    voxels = tuple(lv["voxels"] for lv in levels) + (0,) * (3 - len(levels))
    views_used = max(stats["tiles"]["views_per_tile"])
    estimate = estimate_memory(voxels, stats["keyframes"], tuple(stats["image_size"]), views_used,
                               settings.fusion_chunk, settings.fp16_features, baseline=memory["start_rss_bytes"] or 0)
    total = stats["timings_s"]["total"]
    return {
        "case": case.name,
        "region_m": list(case.region),
        "views": case.views,
        "frames": case.frames,
        "keyframes": stats["keyframes"],
        "tiles": stats["tiles"]["count"],
        "views_per_tile_max": views_used,
        "voxels": [lv["voxels"] for lv in levels],
        "occupied": [lv["occupied"] for lv in levels],
        "mesh_faces": stats.get("mesh", {}).get("faces", 0),
        "timings_s": stats["timings_s"],
        "cpu_timings_s": stats["cpu_timings_s"],
        "keyframes_per_s": stats["keyframes"] / total if total else None,
        "peak_rss_bytes": memory["peak_rss_bytes"],
        "start_rss_bytes": memory["start_rss_bytes"],
        "cuda_max_allocated_bytes": memory["cuda_max_allocated_bytes"],
        "estimated_peak_bytes": estimate.total,
        "message": result.message,
    }


def stereo_cases(cases: tuple[Case, ...]) -> list[Case]:
    """One stereo run per capture and region (stereo has no views per tile): the case with the most views
    of each, so the comparison is with VoRTX at its most expensive setting there."""
    chosen: dict[tuple, Case] = {}
    for case in cases:
        key = (case.region, case.frames)
        if key not in chosen or case.views > chosen[key].views:
            chosen[key] = case
    return list(chosen.values())


def run_stereo_case(case: Case, device: str, workdir: Path, matcher: Optional[str] = None) -> tuple[dict[str, Any], Any]:
    """One run of the classical stereo method (default settings, or another `matcher`) on `case`'s
    capture and region. -> (the run's numbers, its mesh: the texture bake's input)."""

    capture = bench_capture(case, workdir)
    settings = ReconSettings(method="stereo", device=device, max_room_size=case.region)
    if matcher is not None:
        settings = replace(settings, stereo_matcher=matcher)
    result = reconstruct(capture, settings)
    stats = result.stats
    total = stats["timings_s"]["total"]
    return {
        "case": case.name,
        "matcher": settings.stereo_matcher,
        "stereo_stages_s": stats["stereo"].get("stages_s", {}),
        "region_m": list(case.region),
        "frames": case.frames,
        "keyframes": stats["keyframes"],
        "references": stats["stereo"]["references"],
        "stereo_image_size": stats["stereo"]["image_size"],
        "mesh_faces": stats.get("mesh", {}).get("faces", 0),
        "timings_s": stats["timings_s"],
        "cpu_timings_s": stats["cpu_timings_s"],
        "keyframes_per_s": stats["keyframes"] / total if total else None,
        "peak_rss_bytes": stats["memory"]["peak_rss_bytes"],
        "start_rss_bytes": stats["memory"]["start_rss_bytes"],
        "cuda_max_allocated_bytes": stats["memory"]["cuda_max_allocated_bytes"],
        "message": result.message,
    }, result.mesh


def network_seconds(timings: dict[str, float]) -> float:
    """Seconds in the network's own stages: 2D features, view fusion and the 3D CNN at every level."""
    return timings.get("features", 0.0) + stage_sum(timings, "fusion ") + stage_sum(timings, "3D CNN")


def run_evidence_case(case: Case, device: str, workdir: Path, weights: Optional[Path]) -> dict[str, Any]:
    """One run of the learned method with stereo evidence on `case`'s capture and region, default settings."""


    settings = ReconSettings(method="vortx", device=device, max_room_size=case.region)
    if weights is not None:
        model, _, _ = load_network(str(weights), settings.seed, torch.device(device))
    else:
        torch.manual_seed(0)
        model = VortxNet(VortxConfig(**EVIDENCE_WIDTHS, stereo_evidence=StereoEvidenceConfig())).to(device).eval()
    result = run_reconstruction(model, bench_capture(case, workdir), settings, torch.device(device))
    stats = result.stats
    total = stats["timings_s"]["total"]
    return {
        "case": case.name, "weights": str(weights) if weights else "untrained (recipe widths)",
        "keyframes": stats["keyframes"], "voxels": [lv["voxels"] for lv in stats["levels"]],
        "mesh_faces": stats.get("mesh", {}).get("faces", 0), "timings_s": stats["timings_s"],
        "cpu_timings_s": stats["cpu_timings_s"], "network_s": round(network_seconds(stats["timings_s"]), 3),
        "network_cpu_s": round(network_seconds(stats["cpu_timings_s"]), 3),
        "keyframes_per_s": stats["keyframes"] / total if total else None,
        "peak_rss_bytes": stats["memory"]["peak_rss_bytes"], "message": result.message,
    }


def compare_with_stereo(evidence_run: dict[str, Any], stereo_runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The learned run against the stereo run of the same case: CPU seconds per keyframe ratio, extra
    peak RSS, and whether both stay within issue 19's budget."""
    stereo = next(r for r in stereo_runs if r["case"] == evidence_run["case"])
    per_keyframe = lambda run: run["cpu_timings_s"]["total"] / max(run["keyframes"], 1)  # noqa: E731
    cpu_ratio = per_keyframe(evidence_run) / per_keyframe(stereo)
    extra = evidence_run["peak_rss_bytes"] - stereo["peak_rss_bytes"]
    return {"cpu_ratio_per_keyframe": round(cpu_ratio, 3), "extra_peak_rss_bytes": int(extra),
            "within_budget": bool(cpu_ratio <= EVIDENCE_CPU_BUDGET and extra <= EVIDENCE_MEMORY_BUDGET)}


def run_texture_case(case: Case, mesh: Any, texture_size: int, workdir: Path) -> dict[str, Any]:
    """The VR preset's texture bake of `mesh` (made from `case`'s capture) from all that capture's
    photos at `texture_size`: the stages' seconds and the bake's peak RSS."""

    views = views_from_capture(bench_capture(case, workdir))
    options = TextureOptions(texture_size=texture_size)
    started_cpu = time.process_time()
    with PeakMemory() as memory:
        _, stats = textured_result(mesh, views, options)
    return {"case": case.name, "texture_size": texture_size, "photos": len(views), "faces_in": stats["vr"]["faces_in"],
            "faces": stats["faces"], "charts": stats["charts"], "atlas_utilisation": stats["atlas_utilisation"],
            "texels": stats["texels"], "texels_seen": stats["texels_seen"], "timings_s": stats["timings_s"],
            "cpu_s": round(time.process_time() - started_cpu, 2), "peak_rss_bytes": memory.peak_rss,
            "start_rss_bytes": memory.start_rss}


def compare_with_vortx(stereo_run: dict[str, Any], vortx_runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The stereo run against the VoRTX run of the same case: CPU-time ratio, extra peak RSS, and whether
    both stay within the budget (STEREO_CPU_BUDGET x the CPU time, + STEREO_MEMORY_BUDGET bytes)."""
    vortx = next(r for r in vortx_runs if r["case"] == stereo_run["case"])
    cpu_ratio = stereo_run["cpu_timings_s"]["total"] / vortx["cpu_timings_s"]["total"]
    extra = stereo_run["peak_rss_bytes"] - vortx["peak_rss_bytes"]
    return {"vortx_case": vortx["case"], "cpu_ratio": round(cpu_ratio, 3), "wall_ratio":
            round(stereo_run["timings_s"]["total"] / vortx["timings_s"]["total"], 3), "extra_peak_rss_bytes": int(extra),
            "within_budget": bool(cpu_ratio <= STEREO_CPU_BUDGET and extra <= STEREO_MEMORY_BUDGET)}


def stage_sum(timings: dict[str, float], prefix: str) -> float:
    return sum(v for k, v in timings.items() if k.startswith(prefix))


def projected_memory(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The memory model applied to a 10 x 10 x 3 m room at N = 60, 640 x 480, 4 cm."""

    fractions = [[r["occupied"][i] / r["voxels"][i] for r in runs if len(r["voxels"]) > i and r["voxels"][i]] for i in (0, 1)]
    keep = tuple(float(sum(f) / len(f)) if f else 0.5 for f in fractions)
    coarse = coarse_voxels(PROJECTED_ROOM, 0.04)
    models = {
        f"random weights (keep {keep[0]:.2f} / {keep[1]:.2f}, as measured)": keep_fraction_voxels(coarse, keep),  # type: ignore[arg-type]
        "trained weights (surface band, 400 m^2)": surface_band_voxels(coarse, box_room_surface_area(PROJECTED_ROOM), 0.04),
    }
    out = {"room_m": list(PROJECTED_ROOM), "views": 60, "keyframes": PROJECTED_KEYFRAMES, "image_size": list(PROJECTED_IMAGE)}
    for name, voxels in models.items():
        out[name] = estimate_memory(voxels, PROJECTED_KEYFRAMES, PROJECTED_IMAGE, 60).to_dict()
    return out


def markdown(report: dict[str, Any]) -> str:
    m = report["machine"]
    lines = [
        f"Machine: {m['cpu']}, {m['logical_cores']} logical cores, torch {m['torch']} ({m['torch_threads']} threads)"
        + (f", load average {m.get('load_average_at_start')} at start" if m.get("load_average_at_start") else ""),
        "",
        "| case | keyframes | max views/tile | voxels 16/8/4 cm | features s | fusion s | 3D CNN s | mesh + colour s | total s (CPU s) | keyframes/s | peak RSS MB (estimate) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["runs"]:
        t, c = r["timings_s"], r["cpu_timings_s"]
        lines.append(
            f"| {r['case']} | {r['keyframes']} | {r['views_per_tile_max']} | {' / '.join(str(v) for v in r['voxels'])} | {t.get('features', 0):.1f} "
            f"| {stage_sum(t, 'fusion'):.1f} | {stage_sum(t, '3D CNN'):.1f} | {t.get('mesh', 0) + t.get('colour', 0):.1f} "
            f"| {t['total']:.1f} ({c['total']:.1f}) | {r['keyframes_per_s']:.2f} "
            f"| {r['peak_rss_bytes'] / MB:.0f} ({r['estimated_peak_bytes'] / MB:.0f}) |"
        )
    if report.get("stereo_runs"):
        lines += ["", "Stereo fusion (the default method), same captures and regions, default stereo settings; "
                  f"budget: CPU time <= {STEREO_CPU_BUDGET:g}x VoRTX's, peak RSS <= VoRTX's + {STEREO_MEMORY_BUDGET / 2**30:g} GiB:", "",
                  "| case | keyframes | references | " + " | ".join(f"{stage} s" for stage in STEREO_STAGES)
                  + " | total s (CPU s) | keyframes/s | peak RSS MB | CPU vs VoRTX | extra RSS MB | within budget |",
                  "|---" * (len(STEREO_STAGES) + 9) + "|"]
        for r in report["stereo_runs"]:
            t, c, v = r["timings_s"], r["cpu_timings_s"], r["versus_vortx"]
            lines.append(
                f"| {r['case']} | {r['keyframes']} | {r['references']} | " + " | ".join(f"{t.get(stage, 0):.1f}" for stage in STEREO_STAGES)
                + f" | {t['total']:.1f} ({c['total']:.1f}) | {r['keyframes_per_s']:.2f} | {r['peak_rss_bytes'] / MB:.0f} "
                f"| {v['cpu_ratio']:.2f}x | {v['extra_peak_rss_bytes'] / MB:+.0f} | {'yes' if v['within_budget'] else 'NO'} |"
            )
    matcher_runs = [*report.get("stereo_runs", []), *report.get("matcher_runs", [])]
    if report.get("matcher_runs"):
        lines += ["", "Stereo matchers, same captures and regions, default settings otherwise (stereo depth split into "
                  "its stages; seconds per keyframe of the stereo depth stage):", "",
                  "| case | matcher | keyframes | image size | patchmatch s | geometric consistency s | depth filter s "
                  "| stereo depth s | s per keyframe | total s (CPU s) | peak RSS MB |", "|---" * 11 + "|"]
        for r in matcher_runs:
            t, c, st = r["timings_s"], r["cpu_timings_s"], r.get("stereo_stages_s", {})
            stages = " | ".join(f"{st[k]:.1f}" if k in st else "-" for k in ("patchmatch", "geometric consistency", "depth filter"))
            lines.append(
                f"| {r['case']} | {r.get('matcher', '')} | {r['keyframes']} | {'x'.join(map(str, r['stereo_image_size']))} | "
                f"{stages} | {t.get('stereo depth', 0):.1f} | {t.get('stereo depth', 0) / max(1, r['references']):.2f} "
                f"| {t['total']:.1f} ({c['total']:.1f}) | {r['peak_rss_bytes'] / MB:.0f} |")
    if report.get("evidence_runs"):
        lines += ["", "The learned method with stereo evidence, same captures and regions, default settings; "
                  f"budget: CPU time per keyframe <= {EVIDENCE_CPU_BUDGET:g}x stereo fusion's, peak RSS <= its + "
                  f"{EVIDENCE_MEMORY_BUDGET / 2**30:g} GiB:", "",
                  "| case | weights | keyframes | stereo depth s | TSDF fusion s | network s (CPU s) | mesh + colour s "
                  "| total s (CPU s) | peak RSS MB | CPU/keyframe vs stereo | extra RSS MB | within budget |",
                  "|---" * 12 + "|"]
        for r in report["evidence_runs"]:
            t, c, v = r["timings_s"], r["cpu_timings_s"], r["versus_stereo"]
            lines.append(
                f"| {r['case']} | {r['weights']} | {r['keyframes']} | {t.get('stereo depth', 0):.1f} | {t.get('TSDF fusion', 0):.1f} "
                f"| {r['network_s']:.1f} ({r['network_cpu_s']:.1f}) | {t.get('mesh', 0) + t.get('colour', 0):.1f} "
                f"| {t['total']:.1f} ({c['total']:.1f}) | {r['peak_rss_bytes'] / MB:.0f} | {v['cpu_ratio_per_keyframe']:.2f}x "
                f"| {v['extra_peak_rss_bytes'] / MB:+.0f} | {'yes' if v['within_budget'] else 'NO'} |"
            )
    if report.get("texture_runs"):
        lines += ["", "Texture bake (VR preset: small pieces dropped, decimated to the face budget, xatlas atlas, "
                  "every photo at full resolution) of the stereo mesh:", "",
                  "| case | texture px | photos | faces (in) | charts | texels (seen) | atlas s | texels s | bake s "
                  "| total s (CPU s) | peak RSS MB (+ over start) |", "|---" * 11 + "|"]
        for r in report["texture_runs"]:
            t = r["timings_s"]
            lines.append(
                f"| {r['case']} | {r['texture_size']} | {r['photos']} | {r['faces']} ({r['faces_in']}) | {r['charts']} "
                f"| {r['texels']} ({100 * r['texels_seen'] / max(r['texels'], 1):.0f} %) | {t['atlas']:.1f} | {t['texels']:.1f} "
                f"| {t['bake']:.1f} | {t['total']:.1f} ({r['cpu_s']:.1f}) | {r['peak_rss_bytes'] / MB:.0f} "
                f"(+{(r['peak_rss_bytes'] - (r['start_rss_bytes'] or 0)) / MB:.0f}) |"
            )
    lines += ["", "| sparse vs dense 3^3 conv | voxels | kernel map s | sparse fwd s | dense fwd s | speed-up fwd | speed-up fwd+bwd |",
              "|---|---|---|---|---|---|---|"]
    for s in report["sparse_vs_dense"]:
        lines.append(
            f"| {'x'.join(map(str, s['grid']))}, {s['channels']} ch, {s['pattern']} | {s['voxels']} | {s['kernel_map_s']:.3f} "
            f"| {s['sparse_forward_s']:.3f} | {s.get('dense_forward_s', float('nan')):.3f} "
            f"| {s.get('speedup_forward', float('nan')):.2f} | {s.get('speedup_forward_backward', float('nan')):.2f} |"
        )
    p = report["projected_memory"]
    lines += ["", f"Projected peak memory, {p['room_m'][0]:g} x {p['room_m'][1]:g} x {p['room_m'][2]:g} m room, N = {p['views']}, "
              f"{p['keyframes']} keyframes at {p['image_size'][0]}x{p['image_size'][1]}, 4 cm (CPU):"]
    for name, est in p.items():
        if isinstance(est, dict):
            lines.append(f"- {name}: voxels {' / '.join(str(v) for v in est['voxels'])} -> {est['total_bytes'] / 2**30:.1f} GiB "
                         f"(feature cache {est['feature_cache_bytes'] / 2**30:.2f}, fine level {est['fine_level_bytes'] / 2**30:.2f})")
    return "\n".join(lines)


def _option_value(text: str) -> Any:
    """A --profile-set value: an int, a float, a bool or a string."""
    for parse in (int, float):
        try:
            return parse(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def patchmatch_profile(room: Path, size: int, references: int, first: int = 0,
                       overrides: Optional[dict[str, Any]] = None) -> dict[str, Any]:
    """PatchMatch on keyframes first .. first + references - 1 of `room` (poses as given) at a stereo long
    side of `size`, with one torch thread: CPU seconds per keyframe of every stage (stage_clock.py), in
    all and of the depth filter, and the mean depth-map metrics of `engine eval-depth` over those maps."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # CPU seconds of one thread: the shared machine's load does not change them
    try:
        capture = prepare_capture(load_capture(room), sfm=SFM_NEVER).capture
        settings = ReconSettings(method="stereo", stereo_matcher=MATCHER_PATCHMATCH, stereo_image_size=size)
        plan = plan_reconstruction(capture, settings)
        options = replace(stereo_options(settings, torch.device("cpu")), **(overrides or {}))
        usable, _ = posed_frames(capture)
        frames = [capture.frames[i] for i in usable]
        poses = numpy.stack([f.pose for f in frames]).astype(numpy.float64)
        position = {frame_id: p for p, frame_id in enumerate(usable)}
        chosen = list(range(first, min(first + references, len(plan.keyframes))))
        refs = [position[plan.keyframe_ids[k]] for k in chosen]
        points = capture.points if capture.points is not None and len(capture.points) else None
        stages: dict[str, float] = {}
        wall: dict[str, float] = {}
        started = time.process_time()
        with stage_clock.collecting(stages):
            maps = estimate_depth_maps(frames, poses, refs, options, points=points,
                                       bounds=(plan.bounds.minimum, plan.bounds.maximum), stages=wall)
        total = time.process_time() - started
    finally:
        torch.set_num_threads(threads)
    rows = [compare_depth(m.depth, m.confidence, true_depth_at(frames[m.frame], (m.depth.shape[1], m.depth.shape[0])), m.K)
            for m in maps]
    n = max(1, len(maps))
    return {"room": str(room), "size": size, "keyframes": len(maps), "image_size": list(maps[0].depth.shape[::-1]) if maps else None,
            "overrides": overrides or {}, "cpu_s_per_keyframe": total / n,
            "stages_cpu_s_per_keyframe": {k: v / n for k, v in sorted(stages.items())},
            "depth filter_s_per_keyframe": wall.get("depth filter", 0.0) / n,
            "quality": {k: float(numpy.nanmean([r[k] for r in rows])) for k in DEPTH_KEYS}}


def profile_markdown(profiles: list[dict[str, Any]]) -> str:
    """The profiles as one table: a row per stage, a column per run."""
    names = sorted({k for p in profiles for k in p["stages_cpu_s_per_keyframe"]},
                   key=lambda k: (k.startswith("geometric pass/"), k))
    head = ["stage (CPU s per keyframe, 1 thread)"] + [
        f"{p['image_size'][0]}x{p['image_size'][1]}" + "".join(f" {k}={v}" for k, v in p["overrides"].items()) for p in profiles]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for name in names:
        lines.append(f"| {name} | " + " | ".join(f"{p['stages_cpu_s_per_keyframe'].get(name, 0.0):.3f}" for p in profiles) + " |")
    lines.append("| **total** | " + " | ".join(f"**{p['cpu_s_per_keyframe']:.2f}**" for p in profiles) + " |")
    for key in DEPTH_KEYS:
        lines.append(f"| {key} | " + " | ".join(f"{p['quality'][key]:.3f}" for p in profiles) + " |")
    return "\n".join(lines)


def refine_profile(capture_path: Path) -> dict[str, Any]:
    """The default pose refinement of `capture_path`'s given poses, timed: wall and CPU seconds per stage."""
    capture = load_capture(capture_path)
    started, cpu = time.perf_counter(), time.process_time()
    result = refine_poses(capture)
    return {"capture": str(capture_path), "frames": len(result.changes), "adjusted_frames": result.adjusted_frames,
            "points": int(len(result.points)), "error_given_px": result.error_given_px,
            "error_refined_px": result.mean_reprojection_error, "kept_given": result.kept_given,
            "rotation_deg_median": result.rotation_deg_median,
            "stretch_scales": [s.scale for s in result.stretches if s.kind == "stretch"],
            "timings_s": dict(result.timings), "wall_s": time.perf_counter() - started,
            # The parent's CPU only: SIFT, matching and triangulation run in the worker process.
            "parent_cpu_s": time.process_time() - cpu}


def refine_markdown(profile: dict[str, Any]) -> str:
    stages = ("prepare", "extract", "match", "triangulate", "adjust")
    t = profile["timings_s"]
    return "\n".join([
        "| capture | frames (adjusted) | points | error given -> refined px | stretch scales | "
        + " | ".join(f"{s} s" for s in stages) + " | total wall s |",
        "|---|---|---|---|---|" + "---|" * (len(stages) + 1),
        f"| {Path(profile['capture']).name} | {profile['frames']} ({profile['adjusted_frames']}) | {profile['points']} "
        f"| {profile['error_given_px']:.2f} -> {profile['error_refined_px']:.2f} "
        f"| {' / '.join(f'{v:.3f}' for v in profile['stretch_scales'])} | "
        + " | ".join(f"{t.get(s, 0.0):.1f}" for s in stages) + f" | {profile['wall_s']:.1f} |",
    ])


def run(args: argparse.Namespace) -> int:
    if args.real is not None:
        out = args.out if args.out is not None else Path("out") / "real_rooms.json"
        # each run's own records, for looking into one room; never beside the committed table
        return run_suite(args.real, args.quick, args.rooms, args.repeat, out, Path("out") / "real_rooms_runs",
                         features=args.features)
    if args.refine_profile is not None:
        profile = refine_profile(args.refine_profile)
        print(refine_markdown(profile))
        if args.out is not None:
            args.out.write_text(json.dumps(profile, indent=1))
        return 0
    if args.patchmatch_profile is not None:
        overrides = dict((k, _option_value(v)) for k, v in (item.split("=", 1) for item in args.profile_set))
        profiles = []
        for size in args.profile_sizes:
            print(f"profiling PatchMatch at {size} px ...", file=sys.stderr, flush=True)
            profiles.append(patchmatch_profile(args.patchmatch_profile, size, args.profile_references, args.profile_first,
                                               overrides))
        print(profile_markdown(profiles))
        if args.out is not None:
            args.out.write_text(json.dumps(profiles, indent=1))
        return 0
    cases = QUICK_CASES if args.quick else FULL_CASES
    report: dict[str, Any] = {"machine": machine_info(), "quick": bool(args.quick), "image_size": list(IMAGE_SIZE), "runs": []}
    started = time.perf_counter()
    workdir = Path(tempfile.mkdtemp(prefix="vortx-bench-"))
    try:
        for case in cases:
            print(f"running {case.name} ...", file=sys.stderr, flush=True)
            report["runs"].append(run_case(case, args.device, workdir))
            _save_partial(report, args.out)
        report["stereo_runs"], meshes = [], []
        for case in stereo_cases(cases):
            print(f"running stereo fusion on {case.name} ...", file=sys.stderr, flush=True)
            run, mesh = run_stereo_case(case, args.device, workdir)
            run["versus_vortx"] = compare_with_vortx(run, report["runs"])
            report["stereo_runs"].append(run)
            meshes.append((case, mesh))
            _save_partial(report, args.out)
        report["matcher_runs"] = []
        for case, _ in meshes:  # the other stereo matchers on the same captures, their stages apart
            for matcher in STEREO_MATCHERS:
                if matcher == ReconSettings.stereo_matcher:
                    continue
                print(f"running stereo fusion with the {matcher} matcher on {case.name} ...", file=sys.stderr, flush=True)
                report["matcher_runs"].append(run_stereo_case(case, args.device, workdir, matcher)[0])
                _save_partial(report, args.out)
        report["evidence_runs"] = []
        for case, _ in meshes:
            print(f"running the learned method with stereo evidence on {case.name} ...", file=sys.stderr, flush=True)
            run = run_evidence_case(case, args.device, workdir, args.evidence_weights)
            run["versus_stereo"] = compare_with_stereo(run, report["stereo_runs"])
            report["evidence_runs"].append(run)
            _save_partial(report, args.out)
        report["texture_runs"] = []
        case, mesh = meshes[0]
        if len(mesh.faces):
            for size in QUICK_TEXTURE_SIZES if args.quick else TEXTURE_SIZES:
                print(f"texture bake of the stereo mesh of {case.name} at {size} px ...", file=sys.stderr, flush=True)
                report["texture_runs"].append(run_texture_case(case, mesh, size, workdir))
                _save_partial(report, args.out)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    report["sparse_vs_dense"] = []
    for kwargs in QUICK_SPARSE if args.quick else FULL_SPARSE:
        print(f"sparse vs dense {kwargs} ...", file=sys.stderr, flush=True)
        report["sparse_vs_dense"].append(bench_sparse_vs_dense(device=args.device, **kwargs))
    report["projected_memory"] = projected_memory(report["runs"])
    report["bench_seconds"] = round(time.perf_counter() - started, 1)
    if hasattr(os, "getloadavg"):
        report["machine"]["load_average_at_end"] = [round(v, 2) for v in os.getloadavg()]
    print(markdown(report))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1, default=_jsonable) + "\n")
        print(f"\nwrote {args.out}", file=sys.stderr)
    return 0


def _save_partial(report: dict[str, Any], out: Optional[Path]) -> None:
    """The runs so far beside --out (an hour-long run on a busy machine should not lose them to one failure)."""
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".partial.json").write_text(json.dumps(report, indent=1, default=_jsonable) + "\n")


def _jsonable(value: Any) -> Optional[Any]:
    if isinstance(value, tuple):
        return list(value)
    if hasattr(value, "item"):
        return value.item()
    return str(value)
