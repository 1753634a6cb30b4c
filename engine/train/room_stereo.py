"""Plane-sweep stereo depth of a training room, computed from its rendered photos and cached beside them.

Training must see the stereo depth inference will see, never the renderer's exact depth: every
`reference_stride`-th frame of the room is a stereo reference (inference, too, gives maps to at most
`stereo_views` keyframes), matched against all of the room's frames with the options and
scene bounds a default reconstruction uses (engine/recon/stereo_fusion.py `stereo_options`,
engine/recon/scene_bounds.py). The result is written to `<room>/stereo_depth.npz` with the options
that made it; a later run with the same options reads the file instead of sweeping again.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch

from ..capture import load_capture
from ..data.room_folders import find_rooms
from ..errors import VortxError
from ..recon.scene_bounds import scene_bounds
from ..recon.settings import ReconSettings
from ..recon.stereo_fusion import stereo_options
from ..stereo.depth_maps import estimate_depth_maps

STEREO_FILE = "stereo_depth.npz"
FORMAT_VERSION = 2
REFERENCE_STRIDE = 2  # every other frame: half the sweep time, and 20 overlapping maps per 40-frame room


@dataclass
class RoomStereo:
    """Stereo maps of R reference frames of a room.

    frames (R,) int64 positions in the frame order `load_room` uses; depth, confidence (R, h, w)
    float32 (0 = no depth); K (R, 3, 3) in pixels of the maps."""

    frames: np.ndarray
    depth: np.ndarray
    confidence: np.ndarray
    K: np.ndarray

    def map_of_frames(self, frames: np.ndarray) -> np.ndarray:
        """(n,) int64 index into the maps of each frame position in `frames`, -1 where it has none."""
        lookup = np.full(int(max(self.frames.max(initial=-1), np.max(frames, initial=-1))) + 1, -1, np.int64)
        lookup[self.frames] = np.arange(len(self.frames))
        return lookup[np.asarray(frames, np.int64)]


def stereo_cache_path(room: Path) -> Path:
    return Path(room) / STEREO_FILE


def default_stereo_options():
    """The stereo options of a default CPU reconstruction (engine.recon.ReconSettings())."""


    return stereo_options(ReconSettings(), torch.device("cpu"))


def _options_key(options, reference_stride: int) -> str:
    return json.dumps({"format": FORMAT_VERSION, "reference_stride": reference_stride,
                       **{k: v for k, v in asdict(options).items() if k != "device"}}, sort_keys=True)


def room_frames(room: Path):
    """The frames of a room folder that training uses (pose and depth both present), in order."""

    capture = load_capture(Path(room))
    return [f for f in capture.frames if f.pose is not None and f.depth_path is not None]


def load_or_compute_room_stereo(room: Path, options=None, frames=None, log: Optional[callable] = None,
                                reference_stride: int = REFERENCE_STRIDE) -> RoomStereo:
    """The room's stereo maps: read from its cache when made with the same options, else computed
    and cached. frames: the room's frames when the caller has loaded them (`room_frames`)."""

    room = Path(room)
    options = options or default_stereo_options()
    key = _options_key(options, reference_stride)
    path = stereo_cache_path(room)
    if path.is_file():
        try:
            with np.load(path) as data:
                if str(data["options"]) == key:
                    return RoomStereo(data["frames"].astype(np.int64), data["depth"].astype(np.float32), data["confidence"].astype(np.float32),
                                      data["K"].astype(np.float64))
        except (OSError, KeyError, ValueError):
            pass  # unreadable or older cache: compute again
    frames = frames if frames is not None else room_frames(room)
    if not frames:
        raise VortxError(f"room {room}: no frame has both a pose and a depth map")
    poses = np.stack([np.asarray(f.pose, np.float64) for f in frames])
    settings = ReconSettings()
    Ks = np.stack([f.K for f in frames])
    sizes = np.array([[f.width, f.height] for f in frames])
    bounds = scene_bounds(Ks, poses, sizes, settings.frustum_depth, settings.max_room_size)
    if log:
        log(f"stereo depth for {len(frames)} frames of {room.name}")
    references = np.arange(0, len(frames), reference_stride, dtype=np.int64)
    maps = estimate_depth_maps(frames, poses, references.tolist(), options, bounds=(bounds.minimum, bounds.maximum))
    stereo = RoomStereo(references, np.stack([m.depth for m in maps]).astype(np.float32),
                        np.stack([m.confidence for m in maps]).astype(np.float32), np.stack([m.K for m in maps]))
    tmp = path.with_name(path.stem + ".tmp.npz")
    # float16 depth keeps ~1 mm at 2 m and halves the file; confidence needs no more.
    np.savez_compressed(tmp, frames=references, depth=stereo.depth.astype(np.float16), confidence=stereo.confidence.astype(np.float16),
                        K=stereo.K, options=np.array(key))
    tmp.replace(path)
    stereo.depth = stereo.depth.astype(np.float16).astype(np.float32)  # what a cached read returns
    stereo.confidence = stereo.confidence.astype(np.float16).astype(np.float32)
    return stereo


def main(argv: Optional[list[str]] = None) -> int:
    """`python -m engine.train.room_stereo ROOMS_DIR...`: fill the stereo caches (e.g. in parallel)."""

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rooms", nargs="+", type=Path, help="room folders, or folders holding room folders")
    parser.add_argument("--shard", default="0/1", help="i/n: only every n-th room starting at i (parallel runs)")
    args = parser.parse_args(argv)
    index, count = (int(x) for x in args.shard.split("/"))
    rooms = find_rooms(args.rooms)[index::count]
    for room in rooms:
        load_or_compute_room_stereo(room, log=lambda m: print(m, flush=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
