"""Measure the finishing stage (engine/finish) on a run's own depth maps and marching-cubes mesh.

Stereo dominates a run's time (minutes) and the finishing takes about a second, so a run is made once
and each finish mode, or each change to the finishing code, is scored on exactly that mesh and those maps:

    # once: the product's `engine reconstruct` (same flags), its finishing replaced by a recorder
    python scripts/finish_dev.py cache /work/data/sun3d /tmp/sun3d_pm.pkl -- --frame capture \
        --stereo patchmatch --stereo-image-size 200
    # then, as often as needed: finish in each mode and score against the room's truth
    python scripts/finish_dev.py score /tmp/sun3d_pm.pkl /work/data/sun3d --modes off,clean,room --save /tmp/x

A phone export with LiDAR (the 3D Scanner App corridor) is scored against its own held-out depth, as
`engine eval-sensor` scores it (every second photo held out):

    python scripts/finish_dev.py cache-heldout CORRIDOR/All_Data /tmp/corridor.pkl -- --max-room-size 40 40 6
    python scripts/finish_dev.py score-heldout /tmp/corridor.pkl --modes off,room
    # stereo alone from every photo (the LiDAR only as truth), as `eval-sensor --variant stereo --all-photos`
    python scripts/finish_dev.py cache-heldout CORRIDOR/All_Data /tmp/corridor_stereo.pkl -- --variant stereo --all-photos

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


def cache_heldout(capture: Path, out: Path, flags: list[str]) -> None:
    """Reconstruct every other photo of a phone export (as `engine eval-sensor`), recording the mesh and
    maps its finishing gets and the held-out frames with their poses in the reconstruction's world."""
    from dataclasses import replace

    from engine.capture import load_capture
    from engine.eval import sensor_heldout
    from engine.recon import stereo_fusion

    parser = argparse.ArgumentParser()
    sensor_heldout.add_arguments(parser)
    args = parser.parse_args([str(capture), *flags])
    capture_data = load_capture(capture)
    kept, held = sensor_heldout.split_capture(capture_data, args.every)
    if args.all_photos:  # the LiDAR is no input (stereo alone): every photo in, as eval-sensor --all-photos
        if args.variant != "stereo":
            raise SystemExit("--all-photos needs --variant stereo (the sensor depth would be scored against itself)")
        kept = capture_data
    held = [f for f in held if f.sensor_depth is not None and f.pose is not None]
    record: dict = {}

    def recorder(mesh, plan, settings, views=None):
        record.update(mesh=mesh, maps=list(views or []), cams=np.asarray(plan.poses[:, :3, 3]),
                      voxel_size=settings.voxel_size, settings=settings.to_dict())
        raise _Recorded

    stereo_fusion.finish_reconstruction = recorder
    settings = sensor_heldout.settings_from_quality_arguments(args)
    if args.variant == "stereo":
        settings = replace(settings, sensor_depth=False)
    started = time.time()
    real_reconstruct = sensor_heldout.reconstruct

    def reconstruct(capture_in, settings_in, progress=None):
        try:
            real_reconstruct(capture_in, settings_in, progress=progress)
        except _Recorded:
            pass
        raise _Recorded

    sensor_heldout.reconstruct = reconstruct
    prepared = sensor_heldout.prepare_capture(kept, sfm=sensor_heldout.SFM_IF_UNPOSED, check_poses=True,
                                              refine_when_off=not args.keep_poses)
    try:
        reconstruct(prepared.capture, settings)
    except _Recorded:
        pass
    similarity = prepared.similarity
    record["held"] = [(f, similarity.apply_pose(f.pose) if similarity is not None else f.pose) for f in held]
    record["seconds"] = time.time() - started
    with out.open("wb") as file:
        pickle.dump(record, file)
    print(f"recorded {len(record['mesh'].faces)} faces, {len(record['maps'])} depth maps, {len(held)} held out "
          f"in {record['seconds']:.0f} s -> {out}")


def score_heldout(cached: Path, modes: list[str], save: Path | None) -> None:
    from engine.eval.sensor_heldout import compare_to_sensor, mean_of_rows
    from engine.finish.finishing import finish_mesh
    from engine.mesh_io import write_ply

    with cached.open("rb") as file:
        record = pickle.load(file)
    for mode in modes:
        started = time.process_time()
        result = finish_mesh(record["mesh"], record["maps"], record["cams"], record["voxel_size"], mode)
        seconds = time.process_time() - started
        print(mode, f"{seconds:.1f} cpu s", json.dumps({k: v for k, v in result.stats.items() if k != "planes"}))
        for plane in result.planes:
            print("   ", plane.to_dict())
        rows = [r for frame, pose in record["held"] if (r := compare_to_sensor(result.mesh, frame, pose)) is not None]
        mean = mean_of_rows(rows)
        print(f"{mode:<8} within 5 cm {mean['within_5cm']:.3f}  rendered {mean['rendered']:.3f}  "
              f"median {100 * mean['median_error_m']:.1f} cm  normals {mean['normals_30deg']:.3f}  gaps filled {mean['gap_rendered']:.3f}  "
              f"faces {len(result.mesh.faces)}")
        if save is not None:
            save.mkdir(parents=True, exist_ok=True)
            write_ply(save / f"{mode}.ply", result.mesh.vertices, result.mesh.faces, attributes=result.mesh.attributes or None)


def score(cached: Path, truth: Path, modes: list[str], save: Path | None, truth_poses: bool) -> None:
    from engine.data.room_folders import gt_path
    from engine.eval.against_truth import compare_poses, score_mesh, fscore_table, true_poses
    from engine.eval.surface_metrics import surface_table
    from engine.finish import finishing
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
    finishing.SHIFT_SMOOTHING = float(os.environ.get("SIG", finishing.SHIFT_SMOOTHING))
    rows = []
    for mode in modes:
        started = time.process_time()
        result = finish_mesh(record["mesh"], record["maps"], record["cams"], record.get("voxel_size", 0.04), mode,
                             FinishOptions(tolerance=tolerance, refuting_views=int(os.environ.get("REFUTE", "2"))))
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
    ch = sub.add_parser("cache-heldout", help="as cache, for a phone export scored against its held-out LiDAR")
    ch.add_argument("capture", type=Path)
    ch.add_argument("out", type=Path)
    ch.add_argument("flags", nargs=argparse.REMAINDER, help="after --: engine eval-sensor's flags")
    sh = sub.add_parser("score-heldout", help="finish a cache-heldout run in each mode and score it")
    sh.add_argument("cached", type=Path)
    sh.add_argument("--modes", default="off,clean,room")
    sh.add_argument("--save", type=Path)
    args = parser.parse_args()
    if args.command == "cache-heldout":
        cache_heldout(args.capture, args.out, [f for f in args.flags if f != "--"])
    elif args.command == "score-heldout":
        score_heldout(args.cached, args.modes.split(","), args.save)
    elif args.command == "cache":
        cache(args.capture, args.out, [f for f in args.flags if f != "--"])
    else:
        score(args.cached, args.truth, args.modes.split(","), args.save, args.truth_poses)


if __name__ == "__main__":
    main()
