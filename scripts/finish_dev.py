"""Measure the finishing stage (engine/finish) on a run's own depth maps and marching-cubes mesh.

Stereo dominates a run's time (minutes) and the finishing takes about a second, so a run is made once
and each finish mode, or each change to the finishing code, is scored on exactly that mesh and those maps:

    # once: the product's `engine reconstruct` (same flags), its finishing replaced by a recorder
    python scripts/finish_dev.py cache /work/data/sun3d /tmp/sun3d_pm.pkl -- --frame capture \
        --stereo patchmatch --stereo-image-size 200
    # then, as often as needed: finish in each mode and score against the room's truth
    python scripts/finish_dev.py score /tmp/sun3d_pm.pkl /work/data/sun3d --modes off,clean,room --save /tmp/x

`cache` writes the recorded run (world mesh, depth maps, camera centres, the world -> output similarity)
as a pickle (a development file, not a product format). `score` moves each finished mesh to the output
frame and scores it as `engine eval` does (5 cm, trimmed to the truth's observed space). A room whose
truth is in another frame than the output (the demo on its SfM poses) is aligned by the camera-centre
similarity to its truth poses (`--truth-poses`), as `make demo` aligns it.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


class _Recorded(Exception):
    pass


def cache(capture: Path, out: Path, flags: list[str]) -> None:
    """Run `engine reconstruct capture` with `flags`, recording the mesh and maps the finishing gets."""
    from engine import __main__ as entry
    from engine.recon import cli, stereo_fusion

    record: dict = {}
    real_to_output = cli.world_to_output

    def to_output(prepared, frame):
        similarity = real_to_output(prepared, frame)
        record["to_output"] = similarity
        record["estimated"] = {Path(f.image_path).stem: f.pose for f in prepared.capture.posed_frames}
        return similarity

    def recorder(mesh, plan, settings, views=None):
        record.update(mesh=mesh, maps=list(views or []), cams=np.asarray(plan.poses[:, :3, 3]),
                      voxel_size=settings.voxel_size, settings=settings.to_dict())
        raise _Recorded

    cli.world_to_output = to_output
    stereo_fusion.finish_reconstruction = recorder
    started = time.time()
    try:
        entry.main(["reconstruct", str(capture), "--out", str(out.with_suffix(".ply")), *flags])
    except _Recorded:
        pass
    record["seconds"] = time.time() - started
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("wb") as file:
        pickle.dump(record, file)
    print(f"recorded {len(record['mesh'].faces)} faces, {len(record['maps'])} depth maps in {record['seconds']:.0f} s -> {out}")


def score(cached: Path, truth: Path, modes: list[str], save: Path | None, truth_poses: bool) -> None:
    from engine.data.room_folders import gt_path
    from engine.eval.against_truth import compare_poses, score_mesh, fscore_table, true_poses
    from engine.eval.surface_metrics import surface_table
    from engine.finish.finishing import FinishOptions, finish_mesh
    from engine.mesh_io import Mesh, read_ply, write_ply
    from engine.recon.output_frame import moved_mesh
    from engine.tsdf.volume import TsdfVolume

    with cached.open("rb") as file:
        record = pickle.load(file)
    if truth_poses:
        to_truth = compare_poses(record["estimated"], true_poses(truth, sorted(record["estimated"]))).to_truth
    else:
        to_truth = record["to_output"]
    gt, volume = read_ply(truth / "mesh_gt.ply"), TsdfVolume.load(gt_path(truth))
    tolerance = float(os.environ.get("FINISH_TOLERANCE", "0")) or None
    rows = []
    for mode in modes:
        started = time.process_time()
        result = finish_mesh(record["mesh"], record["maps"], record["cams"], record.get("voxel_size", 0.04), mode,
                             FinishOptions(tolerance=tolerance))
        seconds = time.process_time() - started
        print(mode, f"{seconds:.1f} cpu s", json.dumps({k: v for k, v in result.stats.items() if k != "planes"}))
        for plane in result.planes:
            print("   ", plane.to_dict())
        mesh = moved_mesh(Mesh(result.mesh.vertices, result.mesh.faces), to_truth)
        if save is not None:
            save.mkdir(parents=True, exist_ok=True)
            write_ply(save / f"{mode}.ply", mesh.vertices, mesh.faces, attributes=result.mesh.attributes or None)
            if truth_poses:  # also in the capture's own frame (the photos' poses), for capture-view pictures
                own = moved_mesh(Mesh(result.mesh.vertices, result.mesh.faces), record["to_output"])
                write_ply(save / f"{mode}.capture.ply", own.vertices, own.faces, attributes=result.mesh.attributes or None)
        rows.append(score_mesh(mode, mesh, gt, volume))
    if save is not None and truth_poses:
        own = moved_mesh(moved_mesh(gt, to_truth.inverse()), record["to_output"])
        write_ply(save / "truth.capture.ply", own.vertices, own.faces)
    for line in fscore_table(rows):
        print(line)
    print(surface_table({r.name: r.surface for r in rows}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("cache", help="run a reconstruction once and record what its finishing gets")
    c.add_argument("capture", type=Path)
    c.add_argument("out", type=Path)
    c.add_argument("flags", nargs=argparse.REMAINDER, help="after --: engine reconstruct's flags")
    s = sub.add_parser("score", help="finish a recorded run in each mode and score it")
    s.add_argument("cached", type=Path)
    s.add_argument("truth", type=Path, help="the room folder with mesh_gt.ply and its truth TSDF")
    s.add_argument("--modes", default="off,clean,room")
    s.add_argument("--save", type=Path, help="write each mode's mesh (in the truth's frame) here; with --truth-poses "
                   "also MODE.capture.ply and truth.capture.ply in the capture's frame")
    s.add_argument("--truth-poses", action="store_true",
                   help="align by the camera centres to the truth folder's poses (SfM-posed captures)")
    args = parser.parse_args()
    if args.command == "cache":
        cache(args.capture, args.out, [f for f in args.flags if f != "--"])
    else:
        score(args.cached, args.truth, args.modes.split(","), args.save, args.truth_poses)


if __name__ == "__main__":
    main()
