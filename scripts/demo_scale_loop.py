"""Structure from motion on the demo sample's photos, run after run: is the scale from the floor right
every time? (issue 43, deliverable 6)

    .venv/bin/python scripts/demo_scale_loop.py [--runs 30] [--tolerance 0.02] [--out out/demo_scale_loop]

Each run is the product's own photos-only path (`engine.poses.estimate_poses` with the renderer's true
median camera height, as `make demo` runs it). COLMAP's multi-threaded matching and mapping differ from
run to run, so the same photos give slightly different models. Per run it prints and appends to
runs.jsonl the scale error (truth metres per estimated metre), how the floor was found and how high each
camera came out. A run outside the tolerance also leaves its sparse points and camera centres
(run_NN.npz) for a look at what was taken for the floor. Exit code 1 when any run is outside.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from engine.capture import load_capture  # noqa: E402
from engine.poses import SfmOptions, estimate_poses, pose_errors  # noqa: E402


def run_once(sample: Path, truth: dict[str, np.ndarray], true_height: float) -> tuple[dict, np.ndarray, np.ndarray]:
    """One SfM run: (its line for runs.jsonl, sparse points (N, 3), camera centres (C, 3)) in the aligned world."""
    started = time.perf_counter()
    result = estimate_poses(load_capture(sample / "images"), SfmOptions(camera_height=true_height))
    posed = [f for f in result.capture.frames if f.pose is not None]
    errors = pose_errors([f.pose for f in posed], [truth[f.image_path.stem] for f in posed])
    alignment = result.alignment
    height_errors = [float(f.pose[2, 3] - truth[f.image_path.stem][2, 3]) for f in posed]
    line = {
        "scale": round(float(errors["scale"]), 4),  # truth metres per estimated metre
        "registered": len(posed), "photos": len(result.capture.frames), "models": result.model_sizes,
        "floor_method": alignment.floor_method if alignment else None,
        "scale_source": alignment.scale_source if alignment else None,
        "description": alignment.description if alignment else None,
        "median_height_error_m": round(float(np.median(height_errors)), 4),
        "seconds": round(time.perf_counter() - started, 1),
    }
    centres = np.stack([f.pose[:3, 3] for f in posed])
    return line, np.asarray(result.points, np.float64), centres


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sample", type=Path, default=REPO / "samples" / "demo_room")
    parser.add_argument("--runs", type=int, default=30)
    parser.add_argument("--tolerance", type=float, default=0.02, help="largest |scale - 1| that counts as right")
    parser.add_argument("--out", type=Path, default=REPO / "out" / "demo_scale_loop")
    args = parser.parse_args(argv)
    truth_dir = args.sample / "truth" / "pose"
    if not truth_dir.is_dir():
        print(f"error: {truth_dir} is missing: the demo sample's true poses are needed to score the scale", file=sys.stderr)
        return 2
    truth = {p.stem: np.loadtxt(p).reshape(4, 4) for p in truth_dir.glob("*.txt")}
    true_height = float(np.median([pose[2, 3] for pose in truth.values()]))
    args.out.mkdir(parents=True, exist_ok=True)
    outside = 0
    with (args.out / "runs.jsonl").open("a") as log:
        for run in range(args.runs):
            line, points, centres = run_once(args.sample, truth, true_height)
            line["run"] = run
            wrong = abs(line["scale"] - 1.0) > args.tolerance
            if wrong:
                outside += 1
                np.savez(args.out / f"run_{run:02d}.npz", points=points, centres=centres)
            log.write(json.dumps(line) + "\n")
            log.flush()
            print(f"run {run:2d}: scale {line['scale']:.4f} {'OUTSIDE' if wrong else 'ok':7s} "
                  f"{line['registered']}/{line['photos']} photos, floor: {line['floor_method']}, "
                  f"median height error {100 * line['median_height_error_m']:+.1f} cm, {line['seconds']:.0f} s", flush=True)
    print(f"{args.runs - outside} of {args.runs} runs within {100 * args.tolerance:g} % of the true scale "
          f"(lines in {args.out / 'runs.jsonl'})")
    return 1 if outside else 0


if __name__ == "__main__":
    sys.exit(main())
