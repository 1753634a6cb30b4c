"""`python -m engine eval-methods`: held-out rendered rooms reconstructed by each method, side by side.

The reconstruction methods (classical stereo fusion, VoRTX with given weights) are scored exactly as
`eval-weights` scores weights (`engine.eval.heldout.evaluate_rooms`: the same reconstruction settings,
Atlas metrics trimmed to the observed ground-truth voxels, depth metrics on every 4th frame), and the
room box fitted to the ground truth once, as the floor. A method is given as `LABEL=stereo` or
`LABEL=vortx:WEIGHTS` (WEIGHTS a .safetensors path or 'random').
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Optional, Sequence

from ..errors import VortxError
from ..recon.settings import METHODS

ROOM_BOX = "room box"


def parse_method(spec: str) -> tuple[str, dict[str, Any]]:
    """'LABEL=stereo' or 'LABEL=vortx:WEIGHTS' -> (label, ReconSettings overrides)."""
    label, sep, method = spec.partition("=")
    name, _, weights = method.partition(":")
    if not sep or not label or name not in METHODS or (name == "vortx") != bool(weights):
        raise VortxError(f"--methods takes LABEL=stereo or LABEL=vortx:WEIGHTS (a .safetensors path or 'random'), got {spec!r}")
    return label, {"method": name, "weights": weights or None}


def evaluate_methods(
    rooms: Sequence[Path],
    methods: dict[str, dict[str, Any]],
    recon_overrides: Optional[dict[str, Any]] = None,
    out_dir: Optional[Path] = None,
    box: bool = True,
) -> dict:
    """methods: label -> ReconSettings overrides (at least `method`; `weights` for VoRTX), applied over
    `recon_overrides`. Returns {"per_room": {label: {room: metrics}}, "mean": {label: metrics}} with the
    room box last when `box`."""
    from .heldout import evaluate_rooms

    merged: dict[str, dict] = {"per_room": {}, "mean": {}}
    runs = [(label, {label: settings.get("weights")}, {k: v for k, v in settings.items() if k != "weights"})
            for label, settings in methods.items()]
    if box:
        runs.append((ROOM_BOX, {}, {}))  # no method: evaluate_rooms scores only the box
    for label, weights, settings in runs:
        folder = None if out_dir is None else Path(out_dir) / _folder_name(label)
        result = evaluate_rooms(rooms, weights, {**(recon_overrides or {}), **settings}, out_dir=folder,
                                box=label == ROOM_BOX)
        for key in ("per_room", "mean"):
            merged[key].update(result[key])
    return merged


def per_room_table(result: dict, key: str = "fscore") -> str:
    """Markdown: one row per room, one column per method, the metric `key`."""
    labels = [label for label, rooms in result["per_room"].items() if rooms]
    rooms = sorted({room for label in labels for room in result["per_room"][label]})
    lines = ["| room | " + " | ".join(labels) + " |", "|---" * (len(labels) + 1) + "|"]
    for room in rooms:
        cells = [f"{result['per_room'][label][room][key]:.3f}" if room in result["per_room"][label] else "-" for label in labels]
        lines.append(f"| {room} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _folder_name(label: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in label)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rooms", nargs="+", required=True, help="held-out room folders, or folders holding them")
    parser.add_argument("--methods", nargs="+", required=True,
                        help="LABEL=stereo or LABEL=vortx:WEIGHTS (a .safetensors path or 'random')")
    parser.add_argument("--out", default="runs/eval-methods", help="folder for metrics.json and the predicted meshes")
    parser.add_argument("--image-size", type=int, default=128, help="VoRTX image long side (pixels); stereo has its own")
    parser.add_argument("--views", type=int, default=12, help="VoRTX views per tile")
    parser.add_argument("--frustum-depth", type=float, default=3.0, help="scene bounds: frusta cut at this depth (m)")
    parser.add_argument("--max-room-size", type=float, nargs=3, default=[7.0, 7.0, 3.5], help="clip the bounds (m)")
    parser.add_argument("--no-box", action="store_true", help="skip the room-box baseline")


def run(args: argparse.Namespace) -> int:
    from ..data.room_folders import find_rooms
    from .heldout import metrics_table, save_json

    methods = dict(parse_method(spec) for spec in args.methods)
    rooms = find_rooms(args.rooms)
    if not rooms:
        raise VortxError(f"no room folders found in {', '.join(args.rooms)}")
    overrides = dict(image_long_side=args.image_size, views=args.views, frustum_depth=args.frustum_depth,
                     max_room_size=tuple(args.max_room_size))
    out = Path(args.out)
    result = evaluate_methods(rooms, methods, overrides, out_dir=out, box=not args.no_box)
    result["settings"] = overrides
    result["methods"] = methods
    save_json(result, out / "metrics.json")
    print(metrics_table(result))
    print()
    print(per_room_table(result))
    return 0
