"""Handheld-scan camera paths through a synthetic room (pure numpy).

The camera walks a closed loop through the free middle of the room (a wobbly rounded rectangle about
a metre from the walls; furniture is kept clear of it), at 1.2-1.8 m, and looks at walls, furniture
and down at tables. Every turn is smoothed and rate-limited so consecutive frames overlap well (what
SfM and the network's view fusion need), and a little smooth jitter makes it look hand-held.

Poses are camera-to-world (4, 4) in OpenCV camera axes (x right, y down, z forward), world Z up.
"""

from __future__ import annotations

import numpy as np

from ..geometry.cameras import look_along
from .room import RoomSpec

MAX_YAW_STEP = np.radians(12.0)  # per frame: keeps >~80 % image overlap between neighbours at 60 deg HFOV
MAX_PITCH_STEP = np.radians(8.0)


def scan_trajectory(spec: "RoomSpec", n_frames: int, rng: np.random.Generator) -> np.ndarray:
    """(n_frames, 4, 4) camera-to-world poses of a handheld walk around `spec`'s path loop."""
    if n_frames < 1:
        raise ValueError("n_frames must be at least 1")
    positions = _walk_positions(spec, n_frames, rng)
    yaw, pitch = _look_angles(spec, positions, rng)
    roll = _smooth_noise(rng, n_frames, amplitude=np.radians(3.0), correlation=6.0)
    forward = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], axis=1)
    return np.stack([look_along(p, f, roll=r) for p, f, r in zip(positions, forward, roll)])


def _walk_positions(spec: "RoomSpec", n: int, rng: np.random.Generator) -> np.ndarray:
    loop = spec.path.sample(2048)
    closed = np.concatenate([loop, loop[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    # Walk a bit more than once round (loop closure), from a random start, in a random direction.
    turns = rng.uniform(1.0, 1.15)
    start = rng.uniform(0, arc[-1])
    direction = 1.0 if rng.random() < 0.5 else -1.0
    s = (start + direction * np.linspace(0, turns * arc[-1], n, endpoint=False)) % arc[-1]
    xy = np.stack([np.interp(s, arc, closed[:, 0]), np.interp(s, arc, closed[:, 1])], axis=1)
    xy += np.stack([_smooth_noise(rng, n, 0.04, 5.0), _smooth_noise(rng, n, 0.04, 5.0)], axis=1)
    z = np.clip(rng.uniform(1.35, 1.65) + _smooth_noise(rng, n, 0.08, 10.0), 1.2, 1.8)
    return np.concatenate([xy, z[:, None]], axis=1)


def _look_angles(spec: "RoomSpec", positions: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Yaw/pitch per frame: targets chosen every few frames, interpolated, then rate-limited."""
    n = len(positions)
    center = np.array(spec.path.center)
    tables = [p for p in spec.furniture if p.kind == "table"]
    # Small floor items ("dense" clutter) are not aimed at, so a seed walks the same path under every
    # clutter level.
    others = [p for p in spec.furniture if p.kind not in ("table", "item")]
    keys = list(range(0, n, int(rng.integers(4, 8)))) + [n - 1]
    key_yaw, key_pitch = [], []
    for i in keys:
        pos = positions[i]
        outward = np.arctan2(*(pos[:2] - center)[::-1]) if np.linalg.norm(pos[:2] - center) > 1e-6 else 0.0
        target = None
        choice = rng.random()
        if choice < 0.3 and tables:
            target = _nearest_in_view(pos, outward, tables, rng, top=True)
        elif choice < 0.6 and others:
            target = _nearest_in_view(pos, outward, others, rng, top=False)
        if target is None:
            # Across open space: of a few candidate headings (mostly diagonal along the room), take the
            # one whose line of sight runs closest to ~3 m -- not a wall filling the frame at arm's length.
            candidates = outward + np.concatenate([rng.uniform(-1.4, 1.4, 5), np.pi + rng.uniform(-0.7, 0.7, 2)])
            reach = np.array([_free_distance(spec, pos[:2], y) for y in candidates])
            key_yaw.append(float(candidates[np.argmin(np.abs(reach - 3.0))]))
            key_pitch.append(rng.uniform(np.radians(-25), np.radians(5)))
            continue
        delta = target - pos
        key_yaw.append(np.arctan2(delta[1], delta[0]))
        key_pitch.append(np.arctan2(delta[2], np.linalg.norm(delta[:2])))
    key_yaw = np.unwrap(np.array(key_yaw))
    yaw = np.interp(np.arange(n), keys, key_yaw)
    pitch = np.clip(np.interp(np.arange(n), keys, key_pitch), np.radians(-55), np.radians(15))
    yaw = _rate_limit(yaw, MAX_YAW_STEP) + _smooth_noise(rng, n, np.radians(2.0), 3.0)
    pitch = _rate_limit(pitch, MAX_PITCH_STEP) + _smooth_noise(rng, n, np.radians(1.5), 3.0)
    return yaw, pitch


def _nearest_in_view(pos: np.ndarray, outward: float, pieces: list, rng: np.random.Generator, top: bool):
    """A point on a random piece within 3.5 m and within 110 deg of `outward`, or None."""
    candidates = []
    for p in pieces:
        delta = np.array(p.center) - pos[:2]
        dist = np.linalg.norm(delta)
        angle = np.angle(np.exp(1j * (np.arctan2(delta[1], delta[0]) - outward)))
        if 0.8 < dist < 3.5 and abs(angle) < np.radians(110):
            candidates.append(p)
    if not candidates:
        return None
    p = candidates[int(rng.integers(0, len(candidates)))]
    z = p.height if top else rng.uniform(0.3, 1.0) * p.height
    return np.array([p.center[0], p.center[1], z])


def _free_distance(spec: "RoomSpec", xy: np.ndarray, yaw: float) -> float:
    """How far a horizontal line of sight from xy along yaw runs before it meets a wall or a piece of
    furniture taller than 1 m (lower ones are looked over)."""
    d = np.array([np.cos(yaw), np.sin(yaw)])
    with np.errstate(divide="ignore", invalid="ignore"):
        walls = np.where(d > 0, (np.array([spec.length, spec.width]) - xy) / d, np.where(d < 0, -xy / d, np.inf))
    best = float(walls.min())
    for p in spec.furniture:
        if p.height < 1.0:
            continue
        c, s = np.cos(p.yaw), np.sin(p.yaw)
        rot = np.array([[c, s], [-s, c]])  # world -> piece frame
        o, v = rot @ (xy - np.asarray(p.center)), rot @ d
        half = np.asarray(p.footprint) / 2
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - o) / v, (half - o) / v
        t_near = np.nanmax(np.minimum(t1, t2))
        t_far = np.nanmin(np.maximum(t1, t2))
        if t_near <= t_far and t_far > 0:
            best = min(best, max(float(t_near), 0.0))
    return best


def _rate_limit(angles: np.ndarray, max_step: float) -> np.ndarray:
    """Re-integrate a sequence so no step exceeds max_step (then lightly smooth the corners)."""
    out = np.empty_like(angles)
    out[0] = angles[0]
    for i in range(1, len(angles)):
        out[i] = out[i - 1] + np.clip(angles[i] - out[i - 1], -max_step, max_step)
    kernel = np.array([0.25, 0.5, 0.25])
    if len(out) >= 3:
        padded = np.concatenate([out[:1], out, out[-1:]])
        out = np.convolve(padded, kernel, mode="valid")
    return out


def _smooth_noise(rng: np.random.Generator, n: int, amplitude: float, correlation: float) -> np.ndarray:
    """(n,) smooth random signal: white noise blurred with a Gaussian of `correlation` frames, scaled
    to standard deviation `amplitude`."""
    pad = int(3 * correlation) + 1
    white = rng.normal(size=n + 2 * pad)
    x = np.arange(-pad, pad + 1)
    kernel = np.exp(-0.5 * (x / correlation) ** 2)
    smooth = np.convolve(white, kernel / kernel.sum(), mode="valid")[:n]
    smooth = smooth - smooth.mean()  # zero-mean over the sequence: no constant offset
    std = smooth.std() if n > 1 and smooth.std() > 0 else 1.0
    return smooth / std * amplitude
