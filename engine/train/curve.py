"""The learning curve of a training run, on held-out rooms, in the metrics a user sees.

Every `curve_every` steps (and at step 0, before any training) the weights as they are reconstruct
each of the config's `curve_rooms` (rendered rooms never trained on) through the product's own
pipeline (`engine.eval.heldout.evaluate_rooms`), and one line per scored method goes to
`<out_dir>/curve.jsonl`: the step, the F-score, precision, recall and the surface metrics, means over
the rooms and per room. At step 0 the classical stereo method is scored beside it, the baseline the
curve must rise above (an evidence network starts exactly there). `curve_table` prints it for MODEL.md.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

from torch import nn

from ..data.room_folders import find_rooms
from ..eval.heldout import STEREO_METHOD, evaluate_rooms
from ..eval.surface_metrics import SURFACE_KEYS
from .config import TrainConfig

CURVE_FILE = "curve.jsonl"
CURVE_KEYS = ("fscore", "prec", "recall") + SURFACE_KEYS
LEARNED, CLASSICAL = "learned", "stereo"


def curve_due(cfg: TrainConfig, step: int) -> bool:
    """Whether the curve gets a point at `step` (step 0 = before training)."""
    return bool(cfg.curve_rooms) and cfg.curve_every > 0 and step % cfg.curve_every == 0


def score_point(net: nn.Module, cfg: TrainConfig, step: int, out: Path) -> list[dict]:
    """Reconstruct and score the curve rooms with `net` as it is now; append and return the lines."""
    from ..model.weights import save_weights

    rooms = find_rooms([cfg.resolve(r) for r in cfg.curve_rooms])
    if not rooms:
        raise ValueError(f"curve_rooms {cfg.curve_rooms} hold no room folders")
    was_training = net.training
    net.eval()
    weights = save_weights(net, net.config, out / "curve_weights.safetensors")
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

