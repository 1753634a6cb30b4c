"""The learning curve of a training run, on held-out rooms, in the metrics a user sees.

Every `curve_every` steps (and at step 0, before any training) the weights as they are reconstruct
each of the config's `curve_rooms` (rendered rooms never trained on) through the product's own
pipeline (`engine.eval.heldout.evaluate_rooms`), and one line per scored method goes to
`<out_dir>/curve.jsonl`: the step, the F-score, precision, recall and the surface metrics, means over
the rooms and per room. At step 0 the classical stereo method is scored beside it, the baseline the
curve must rise above (an evidence network starts exactly there). `curve_table` prints it for docs/experiments.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
from torch import nn

from ..data.room_folders import find_rooms
from ..eval.heldout import STEREO_METHOD, evaluate_rooms
from ..eval.surface_metrics import SURFACE_KEYS
from ..model.weights import save_weights
from .config import TrainConfig

CURVE_FILE = "curve.jsonl"
CURVE_KEYS = ("fscore", "prec", "recall") + SURFACE_KEYS
LEARNED, CLASSICAL = "learned", "stereo"


def curve_due(cfg: TrainConfig, step: int) -> bool:
    """Whether the curve gets a point at `step` (step 0 = before training)."""
    return bool(cfg.curve_rooms) and cfg.curve_every > 0 and step % cfg.curve_every == 0


def score_point(net: nn.Module, cfg: TrainConfig, step: int, out: Path) -> list[dict]:
    """Reconstruct and score the curve rooms with `net` as it is now; append and return the lines."""

    rooms = find_rooms([cfg.resolve(r) for r in cfg.curve_rooms])
    if not rooms:
        raise ValueError(f"curve_rooms {cfg.curve_rooms} hold no room folders")
    was_training = net.training
    net.eval()
    # Each point's weights are kept, so a point can be scored again later (another room, another rule).
    weights = save_weights(net, net.config, out / "curve_weights" / f"step_{step:06d}.safetensors")
    net.train(was_training)
    methods = {LEARNED: str(weights)}
    if step == 0:
        methods[CLASSICAL] = STEREO_METHOD
    overrides = {k: tuple(v) if isinstance(v, list) else v for k, v in cfg.curve_settings.items()}  # JSON lists
    result = evaluate_rooms(rooms, methods, overrides, box=False)
    lines = []
    for label in methods:
        per_room = {room: {k: m[k] for k in CURVE_KEYS} for room, m in result["per_room"][label].items()}
        mean = {k: result["mean"][label][k] for k in CURVE_KEYS}
        lines.append({"step": step, "method": label, **mean, "rooms": per_room})
    with open(out / CURVE_FILE, "a") as f:
        for line in lines:
            f.write(json.dumps(line) + "\n")
    return lines


def read_curve(path: Path) -> list[dict]:
    path = Path(path)
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def has_point(path: Path, step: int) -> bool:
    return any(line["step"] == step for line in read_curve(path))


def curve_table(lines: list[dict], keys: Optional[tuple[str, ...]] = None) -> str:
    """A Markdown table of the curve: one row per step and method."""
    keys = keys or CURVE_KEYS
    head = "| step | method | " + " | ".join(keys) + " |"
    rows = [head, "|" + "---|" * (len(keys) + 2)]
    for line in sorted(lines, key=lambda l: (l["step"], l["method"] != CLASSICAL)):
        cells = [f"{line[k]:.0f}" if k == "pieces" else f"{line[k]:.3f}" for k in keys]
        rows.append(f"| {line['step']} | {line['method']} | " + " | ".join(cells) + " |")
    return "\n".join(rows)



PLOT_KEYS = (("fscore", "F-score"), ("normal_agreement", "normal agreement"), ("floater_share", "floater share"))


def plot_curve(lines: list[dict], path: Path, size: tuple[int, int] = (360, 240)) -> Path:
    """A PNG with one panel per PLOT_KEYS metric: the learned method's curve over the steps (blue) and the
    classical stereo method at step 0 as a flat line (red), each panel scaled to its own range."""
    width, height = size
    learned = sorted((l for l in lines if l["method"] == LEARNED), key=lambda l: l["step"])
    classical = next((l for l in lines if l["method"] == CLASSICAL), None)
    if not learned:
        raise ValueError("the curve has no point of the learned method")
    last_step = max(max(l["step"] for l in learned), 1)
    panels = []
    for key, title in PLOT_KEYS:
        image = np.full((height, width, 3), 255, np.uint8)
        values = [l[key] for l in learned] + ([classical[key]] if classical else [])
        lo, hi = min(values), max(values)
        pad = max(0.02, 0.1 * (hi - lo))
        lo, hi = lo - pad, hi + pad
        left, right, top, bottom = 48, width - 12, 28, height - 30

        def xy(step: float, value: float) -> tuple[int, int]:
            return (int(left + (right - left) * step / last_step), int(bottom - (bottom - top) * (value - lo) / (hi - lo)))

        cv2.rectangle(image, (left, top), (right, bottom), (180, 180, 180), 1)
        for value in (lo + pad, hi - pad):
            cv2.putText(image, f"{value:.3f}", (2, xy(0, value)[1] + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (80, 80, 80), 1)
        if classical:
            cv2.line(image, xy(0, classical[key]), xy(last_step, classical[key]), (0, 0, 220), 1)
        points = np.array([xy(l["step"], l[key]) for l in learned], np.int32)
        cv2.polylines(image, [points], False, (200, 80, 0), 2)
        for p in points:
            cv2.circle(image, tuple(int(c) for c in p), 3, (200, 80, 0), -1)
        cv2.putText(image, title, (left, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1)
        cv2.putText(image, f"step {last_step}", (right - 70, height - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (80, 80, 80), 1)
        cv2.putText(image, "learned", (left, height - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (200, 80, 0), 1)
        if classical:
            cv2.putText(image, "stereo fusion", (left + 62, height - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 220), 1)
        panels.append(image)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.concatenate(panels, axis=1))
    return path


def main(argv: Optional[list[str]] = None) -> int:
    """`python -m engine.train.curve RUN_DIR [--png PATH]`: the run's curve as a Markdown table (and a plot)."""
    parser = argparse.ArgumentParser(prog="python -m engine.train.curve", description=main.__doc__)
    parser.add_argument("run", type=Path, help="the training run's out_dir (holds curve.jsonl)")
    parser.add_argument("--png", type=Path, default=None, help="also plot F, normal agreement and floaters here")
    args = parser.parse_args(argv)
    lines = read_curve(args.run / CURVE_FILE)
    if not lines:
        print(f"{args.run / CURVE_FILE} holds no curve point yet")
        return 1
    print(curve_table(lines))
    if args.png:
        print(f"wrote {plot_curve(lines, args.png)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
