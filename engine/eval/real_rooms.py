"""`python -m engine bench --real [DATA_DIR]`: every real room with truth, every default, one table.

The rooms are the manifest's (real_rooms_manifest.json: where each comes from, its licence, how it is
scored), found under the data folder (`../data` beside the checkout by default; scripts/fetch_real_rooms.py
fetches them), plus any rendered room with truth there (`engine synth`). A room that is not there is
listed as missing, not failed. Per room:

- `default`: the whole default path a user gets: the capture as it comes, the pose check and
  refinement, every reconstruction default (a phone capture with stereo alone: its LiDAR is the truth);
- `finish off`: the same run's mesh before the finishing (Finish Off gives exactly that mesh), so the
  finishing's gain is measured without a second run's spread;
- `photos alone`: the photos with their poses, intrinsics and depth stripped, posed by structure from
  motion, the mesh moved onto the truth by the similarity that fits the camera centres (`--features
  learned`: posed with the learned features, recorded as "photos alone (learned)", beside SIFT's);
- `room box`: the box fitted to the truth, scored the same way: the metric's floor.

Phone captures (kind "phone") are scored as `engine eval-sensor --all-photos` scores them: every photo in,
the confident LiDAR of every second frame fused at 4 cm as the truth. Rooms with a truth mesh (kind
"room", "photos") against it, trimmed to its observed voxels. Kind "time" (no truth) gives time, memory
and pieces. Each reconstruction runs in a process of its own, so its peak memory is its own (RSS of
that process and of its SfM worker, the larger) and a crash fails one row, not the suite.

The table is printed beside the last committed one (docs/real_rooms.json at HEAD), each figure that got
worse by more than its run-to-run spread flagged with "!": the spread recorded with the room (`--repeat
2` measures it: the largest difference between the runs), else SPREAD's.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..capture import load_capture
from ..data.room_folders import find_rooms as rendered_rooms, gt_path, precompute_room
from ..errors import VortxError
from ..mesh_io import read_ply
from ..poses.prepare import SFM_IF_UNPOSED, prepare_capture
from ..poses.sfm import SfmOptions
from ..recon.driver import reconstruct
from ..recon.settings import ReconSettings
from ..tsdf.volume import TsdfVolume
from .against_truth import compare_poses, score_mesh, true_poses
from .room_box import room_box_from_tsdf
from .sensor_heldout import evaluate_variant, held_out_surface, moved, photos_alone, split_capture, surface_scores
from .surface_metrics import clean_faces, mesh_topology

REPO = Path(__file__).resolve().parents[2]
MANIFEST = Path(__file__).with_name("real_rooms_manifest.json")
DEFAULT_DATA = REPO.parent / "data"
COMMITTED = "docs/real_rooms.json"
KINDS = ("phone", "room", "photos", "time")
FIGURES = ("fscore", "precision", "recall", "normals", "floaters", "pieces", "area_ratio", "wall_s", "peak_gb")
# Worse is lower for these, higher for the rest.
HIGHER_IS_BETTER = {"fscore", "precision", "recall", "normals"}
# Run-to-run spread assumed where a room has none measured (`--repeat`): the corridor, the demo and the
# 200-frame render have repeated within these (F 0.003-0.004 between runs; wall 10 % on a shared machine).
SPREAD = {"fscore": 0.01, "precision": 0.01, "recall": 0.01, "normals": 0.01, "floaters": 0.005,
          "pieces": 0.1, "area_ratio": 0.02, "wall_s": 0.1, "peak_gb": 0.1}
RELATIVE_SPREAD = {"pieces", "wall_s", "peak_gb"}  # spreads given as a share of the figure


@dataclass(frozen=True)
class Room:
    name: str
    path: Path
    kind: str
    what: str
    quick: bool
    # Photos alone from every n-th photo: a 10 Hz video's 660 frames are not what a user photographs,
    # and SfM over all of them takes 20 minutes (the ARKitScenes kitchen); n photos a second are.
    photos_alone_every: int = 1


def manifest() -> list[dict[str, Any]]:
    return json.loads(MANIFEST.read_text())["rooms"]


def room_path(folder: str, data: Path) -> Path:
    """Where a manifest folder is: `@repo/...` in this checkout, `@shared/...` beside it, else under `data`."""
    if folder.startswith("@repo/"):
        return REPO / folder[len("@repo/"):]
    if folder.startswith("@shared/"):
        return REPO.parent / "shared" / folder[len("@shared/"):]
    return data / folder


def find_rooms(data: Path, quick: bool = False, names: Optional[list[str]] = None) -> tuple[list[Room], list[str]]:
    """(the rooms present, a line for each manifest room missing, saying how to fetch it)."""

    rooms, missing, known = [], [], set()
    for entry in manifest():
        path = room_path(entry["folder"], data)
        known.add(path.resolve())
        if names and entry["name"] not in names or quick and not entry["quick"]:
            continue
        if path.exists():
            rooms.append(Room(entry["name"], path, entry["kind"], entry["what"], entry["quick"],
                              entry.get("photos_alone_every", 1)))
        else:
            missing.append(f"{entry['name']}: not at {path} (python scripts/fetch_real_rooms.py {data})")
    if data.is_dir() and not quick:
        for path in rendered_rooms([data]):
            if path.resolve() not in known and (not names or path.name in names):
                rooms.append(Room(path.name, path, "room", "a rendered room (engine synth)", False))
    return rooms, missing


# ------------------------------------------------------------------------------ one run, its process


def peak_gb() -> float:
    """The larger of this process's and its finished children's (the SfM worker's) peak RSS."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return round(max(own, children) / 1024 ** 2, 2)  # ru_maxrss is in KiB on Linux


def figures(scores: Optional[dict[str, Any]]) -> dict[str, Any]:
    """The record's figures from `surface_scores` / `score_mesh` output (None: no truth)."""
    if scores is None:
        return {k: None for k in FIGURES[:7]}
    return {"fscore": scores["fscore"], "precision": scores["prec"], "recall": scores["recall"],
            "normals": scores["normal_agreement"], "floaters": scores["floater_share"], "pieces": scores["pieces"],
            "area_ratio": scores["area_ratio"]}


def photos_alone_name(features: str) -> str:
    """The record's variant for photos alone posed with `features` (SIFT's keeps its plain name)."""
    return "photos alone" if features == SfmOptions.features else f"photos alone ({features})"


def run_phone(room: Room, photos_only: bool, features: str = SfmOptions.features) -> list[dict[str, Any]]:
    capture = load_capture(room.path)
    _, held = split_capture(capture, 2)
    held = [f for f in held if f.sensor_depth is not None and f.pose is not None]
    if not held:
        raise VortxError(f"{room.path}: no frame has both a pose and sensor depth to score against")
    kept = capture.with_frames(capture.frames[::room.photos_alone_every]) if photos_only else capture
    result = evaluate_variant(kept, held, replace(ReconSettings(), sensor_depth=False), photos_only=photos_only,
                              sfm_options=SfmOptions(features=features))
    name = photos_alone_name(features) if photos_only else "default"
    records = [{"variant": name, **figures(result["surface"]), "wall_s": result["seconds"],
                "extra": {"faces": result["faces"], "poses_found": result["poses_found"],
                          "within_5cm_per_pixel": result["mean"]["within_5cm"]}}]
    records.append({"variant": "finish off" if not photos_only else f"{name}, finish off",
                    **figures(result["surface_unfinished"]), "wall_s": result["seconds"]})
    if not photos_only:
        truth = held_out_surface(held)
        records.append({"variant": "room box", **figures(surface_scores(room_box_from_tsdf(truth.volume), truth)),
                        "wall_s": 0.0})
    return records


def run_with_truth(room: Room, photos_only: bool, features: str = SfmOptions.features) -> list[dict[str, Any]]:
    """A room with a truth mesh: a rendered room or SUN3D (kind "room": posed), the demo (kind
    "photos": its photos only, truth/ beside them). Also kind "time" (no truth: scores None)."""

    truth_dir = room.path / "truth" if room.kind == "photos" else room.path
    capture = load_capture(room.path / "images" if room.kind == "photos" else room.path)
    started = time.perf_counter()
    prepared = prepare_capture(photos_alone(capture) if photos_only else capture, sfm=SFM_IF_UNPOSED,
                               check_poses=True, refine_when_off=True, sfm_options=SfmOptions(features=features))
    result = reconstruct(prepared.capture, ReconSettings())
    seconds = round(time.perf_counter() - started, 1)
    extra: dict[str, Any] = {"faces": int(len(result.mesh.faces)), "frames": len(capture.frames)}
    if room.kind == "time":
        pieces = mesh_topology(*clean_faces(result.mesh)).pieces
        return [{"variant": "default", **figures(None), "pieces": pieces, "wall_s": seconds, "extra": extra}]
    if photos_only or prepared.ran_sfm:
        stems = [f.image_path.stem for f in capture.frames]
        comparison = compare_poses({f.image_path.stem: f.pose for f in prepared.capture.frames if f.pose is not None},
                                   true_poses(truth_dir, stems) if room.kind == "photos" else
                                   {f.image_path.stem: f.pose for f in capture.frames if f.pose is not None})
        to_truth = comparison.to_truth
        extra["poses_found"] = {"registered": len(comparison.stems), "photos": len(capture.frames),
                                "scale_source": prepared.scale_source,
                                **{k: float(v) for k, v in comparison.errors.items()}}
    else:
        to_truth = prepared.similarity.inverse() if prepared.similarity is not None else None
    volume = TsdfVolume.load(gt_path(truth_dir) or precompute_room(truth_dir))
    truth = read_ply(truth_dir / "mesh_gt.ply")

    def scored(mesh) -> dict[str, Any]:
        scores = score_mesh("", moved(mesh, to_truth), truth, volume)
        return figures({**scores.mesh.as_dict(), **scores.surface.as_dict()})

    name = photos_alone_name(features) if photos_only and room.kind != "photos" else "default"
    if room.kind == "photos" and features != SfmOptions.features:
        name = f"default ({features})"
    records = [{"variant": name, **scored(result.mesh), "wall_s": seconds, "extra": extra}]
    if result.unfinished_mesh is not None:
        records.append({"variant": "finish off" if name == "default" else f"{name}, finish off",
                        **scored(result.unfinished_mesh), "wall_s": seconds})
    if (not photos_only or room.kind == "photos") and features == SfmOptions.features:
        box = score_mesh("", room_box_from_tsdf(volume), truth, volume)
        records.append({"variant": "room box", **figures({**box.mesh.as_dict(), **box.surface.as_dict()}),
                        "wall_s": 0.0})
    return records


def runs_of(room: Room, features: str = SfmOptions.features) -> list[str]:
    """The reconstructions a room gets: "default" (scored as default and finish off) and "photos alone";
    with other `features` than the default, only the runs that pose photos alone, with them."""
    if features != SfmOptions.features:  # the demo's default is its photos alone; the fox has no truth
        return {"photos": ["default"], "time": []}.get(room.kind, ["photos alone"])
    if room.kind in ("photos", "time"):
        return ["default"]
    return ["default", "photos alone"]


def run_child(room: Room, run: str, features: str = SfmOptions.features) -> list[dict[str, Any]]:
    photos_only = run == "photos alone"
    records = (run_phone(room, photos_only, features) if room.kind == "phone" else
               run_with_truth(room, photos_only, features))
    peak = peak_gb()
    for record in records:
        record["peak_gb"] = peak if record["variant"] != "room box" else None
    return records


# ------------------------------------------------------------------------------------- the suite


def commit_of_checkout() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO, capture_output=True,
                               text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")


def committed_records() -> list[dict[str, Any]]:
    """docs/real_rooms.json as last committed ([] before the first)."""
    try:
        shown = subprocess.run(["git", "show", f"HEAD:{COMMITTED}"], cwd=REPO, capture_output=True, text=True, check=True)
        return json.loads(shown.stdout)["records"]
    except (OSError, subprocess.CalledProcessError, ValueError, KeyError):
        return []


def spawn(room: Room, run: str, out: Path, quiet: bool, features: str = SfmOptions.features) -> list[dict[str, Any]]:
    """One run in a process of its own; its records, or one failed record saying why."""
    command = [sys.executable, "-m", "engine.eval.real_rooms", "--child", str(room.path), room.kind, room.name, run,
               str(out), str(room.photos_alone_every), features]
    started = time.perf_counter()
    done = subprocess.run(command, cwd=REPO, stdout=subprocess.DEVNULL if quiet else None,
                          stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    if done.returncode != 0 or not out.is_file():
        why = (done.stderr.strip().splitlines() or ["no message"])[-1]
        return [{"variant": run, **figures(None), "wall_s": round(time.perf_counter() - started, 1), "peak_gb": None,
                 "failed": why}]
    return json.loads(out.read_text())


def worse(record: dict[str, Any], before: dict[str, Any], key: str) -> bool:
    """Whether `key` got worse from `before` to `record` by more than its spread."""
    new, old = record.get(key), before.get(key)
    if new is None or old is None:
        return False
    spread = (record.get("spread") or {}).get(key, before.get("spread", {}).get(key) if before.get("spread") else None)
    if spread is None:
        spread = SPREAD[key] * abs(old) if key in RELATIVE_SPREAD else SPREAD[key]
    change = old - new if key in HIGHER_IS_BETTER else new - old
    return change > spread


def table(records: list[dict[str, Any]], previous: list[dict[str, Any]]) -> str:
    """Markdown: one row per room and variant, each figure beside the last committed one, "!" where worse."""
    last = {(r["room"], r["variant"]): r for r in previous}
    head = "| room | variant | " + " | ".join(FIGURES) + " |"
    lines = [head, "|" + "---|" * (len(FIGURES) + 2)]
    for record in records:
        before = last.get((record["room"], record["variant"]), {})
        cells = []
        for key in FIGURES:
            value = record.get(key)
            text = "-" if value is None else f"{value:.3f}" if isinstance(value, float) and key not in ("wall_s",) \
                else f"{value:.0f}" if key == "wall_s" else str(value)
            if before.get(key) is not None and value is not None:
                old = before[key]
                text += f" ({old:.0f})" if key in ("wall_s", "pieces") else f" ({old:.3f})"
                if worse(record, before, key):
                    text = "**" + text + " !**"
            cells.append(text)
        failed = f" failed: {record['failed']}" if record.get("failed") else ""
        lines.append(f"| {record['room']} | {record['variant']}{failed} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def with_spread(runs: list[list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """The first run's records, each with the spread of the runs per figure (largest minus smallest)."""
    first = runs[0]
    for index, record in enumerate(first):
        same = [run[index] for run in runs if index < len(run) and run[index]["variant"] == record["variant"]]
        if len(same) > 1:
            record["spread"] = {key: round(max(r[key] for r in same) - min(r[key] for r in same), 4) for key in FIGURES
                                if all(r.get(key) is not None for r in same)}
    return first


def run_suite(data: Path, quick: bool, names: Optional[list[str]], repeat: int, out: Optional[Path],
              workdir: Path, quiet: bool = False, features: str = SfmOptions.features) -> int:
    rooms, missing = find_rooms(data, quick, names)
    for line in missing:
        print(f"missing {line}", file=sys.stderr)
    if not rooms:
        raise VortxError(f"no real room found under {data}: fetch them with `python scripts/fetch_real_rooms.py {data}`")
    commit = commit_of_checkout()
    records: list[dict[str, Any]] = []
    workdir.mkdir(parents=True, exist_ok=True)
    for room in rooms:
        for run in (runs_of(room, features)[:1] if quick else runs_of(room, features)):
            print(f"== {room.name}: {run}" + (f" ({features} features)" if features != SfmOptions.features else ""),
                  file=sys.stderr, flush=True)
            repeats = [spawn(room, run, workdir / f"{room.name}-{run.replace(' ', '_')}-{features}-{i}.json", quiet, features)
                       for i in range(max(repeat, 1))]
            for record in with_spread(repeats):
                records.append({"room": room.name, "commit": commit, **record})
            if out is not None:  # partial results survive an interrupted suite
                write_records(records, out)
    print(table(records, committed_records()))
    return 0


def write_records(records: list[dict[str, Any]], out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"about": "python -m engine bench --real: docs/results.md explains the columns",
                               "records": records}, indent=1) + "\n")


def child_main(argv: list[str]) -> int:
    path, kind, name, run, out, every, features = argv
    room = Room(name, Path(path), kind, "", False, int(every))
    try:
        records = run_child(room, run, features)
    except VortxError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    Path(out).write_text(json.dumps(records, default=lambda v: float(v) if isinstance(v, np.floating) else int(v)))
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--child"]:
        sys.exit(child_main(sys.argv[2:]))
    sys.exit("usage: python -m engine bench --real [DATA_DIR] (this module's --child is the suite's own)")
