"""A bent SfM model found by each photo's own vertical lines, and cut where it bends.

Incremental SfM walking straight down plain walls (the 3D Scanner App corridor: 0.5 m steps towards
its end door, with features only on the door and the floor seams) can turn a few photos' rotations
3-10 deg the wrong way; the photos registered after them inherit the turn and the whole model bends
(three of four mapper runs on one database of that corridor: 0.5-1.6 m mean camera error against the
phone's ARKit poses, against 15 cm for the fourth). Bundle adjustment keeps such a bend: every photo
still reprojects its points to a pixel.

Gravity is one direction for every photo, so each photo's own vertical lines (`vertical_lines.photo_up`)
say how far its pose leans from the rest. In a straight model every photo's up is within 1-2 deg of
the capture's (now and then one photo with few lines 4 deg); in a bent one a stretch of consecutive
photos leans 6-20 deg. `find_bend` looks for such stretches among the photos the vertical-line search
samples (`vertical_lines.evenly_spaced`): at least BEND_MIN_PHOTOS photos leaning over BEND_TILT_DEG,
each within BEND_GAP sampled photos of the next, leaning together (one rigid part of the model turned
one way). Where the photos' lines disagree all along (the median photo leans over BEND_AGREEMENT_DEG:
the fox's published poses, 0.3-21 deg, an object's near-vertical edges that are not vertical), they
measure nothing and no bend is looked for. The walk is then cut there: the longest stretch of
the walk between bends is kept and the rest left unposed, so the result is a smaller room that is
right instead of a whole one that is bent. Only a lean shows this way; a bend about the vertical
(the walk turned left or right too far) keeps the photos' up and is not found.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from ..capture.model import Frame
from ..geometry.cameras import mean_up_direction
from ..capture.vertical_lines import MIN_PHOTOS, evenly_spaced, photo_segments, photo_up, up_from_segments

BEND_TILT_DEG = 3.0
BEND_MIN_PHOTOS = 3
BEND_GAP = 2
BEND_TOGETHER_DEG = 2.0
BEND_AGREEMENT_DEG = 1.0  # the median photo's lean: above it the lines do not measure the poses


@dataclass(frozen=True)
class Bend:
    """Where a model bends: `kept` and `cut` index the frames given to `find_bend` (capture order)."""

    kept: list[int]  # the longest straight stretch of the walk
    cut: list[int]  # posed frames left out: the leaning stretches and the walk beyond them
    leaning: list[tuple[int, int]]  # (first, last) of each leaning stretch
    tilts_deg: list[float]  # how far each leaning sampled photo leans

    def describe(self, names: Sequence[str]) -> str:
        stretches = ", ".join(f"{names[a]}..{names[b]}" for a, b in self.leaning)
        return (f"the poses bend: the vertical lines of photos {stretches} lean {np.median(self.tilts_deg):.0f} deg "
                f"(median) from the other photos' up, so their poses are off (a walk straight along plain walls or a "
                f"fast turn); only the {len(self.kept)} photos {names[self.kept[0]]}..{names[self.kept[-1]]} are used, "
                f"{len(self.cut)} posed photos are left out. Retake that stretch with more texture in view, or use "
                "the phone app's own poses")


def photo_tilts(frames: Sequence[Frame]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sampled (S,) int64 indices into `frames`, ups (S, 3) world axes, tilts (S,) deg; NaN where a
    photo's lines do not pin its up down): each sampled photo's own up and how far it leans from the
    capture's, all as the posed `frames` (capture order) place them. Empty when the photos show too
    few vertical lines."""
    empty = np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)
    if len(frames) < MIN_PHOTOS:
        return empty
    sampled = evenly_spaced(len(frames))
    segments = photo_segments([frames[i] for i in sampled])
    prior = mean_up_direction(np.stack([frames[i].pose for i in sampled]))
    capture_up = up_from_segments(segments, prior)
    if capture_up is None:
        return empty
    ups = np.full((len(sampled), 3), np.nan)
    for k, (normals, lengths) in enumerate(segments):
        up = photo_up(normals, lengths, capture_up.up)
        if up is not None:
            ups[k] = up
    tilts = np.degrees(np.arccos(np.clip(ups @ capture_up.up, -1.0, 1.0)))
    return sampled, ups, tilts


def find_bend(frames: Sequence[Frame]) -> Optional[Bend]:
    """Where the posed `frames` (capture order, each with pose and K) bend, or None when no stretch of
    them leans, or their photos' vertical lines cannot tell (too few, or they disagree all along: a
    scene whose near-vertical lines are not vertical, such as an object photographed from all round)."""
    sampled, ups, tilts = photo_tilts(frames)
    defined = np.flatnonzero(~np.isnan(tilts))
    if len(defined) < 2 * BEND_MIN_PHOTOS or np.median(tilts[defined]) > BEND_AGREEMENT_DEG:
        return None
    leaning = defined[tilts[defined] > BEND_TILT_DEG]
    # Stretches of leaning sampled photos, each within BEND_GAP of the next, leaning together (a bent
    # model's part is rigid: its photos share one wrong up); a lone one is a photo with few lines.
    groups = [g for g in _groups(leaning, BEND_GAP) if len(g) >= BEND_MIN_PHOTOS and _together(ups[g])]
    if not groups:
        return None
    # The walk between bends: from the photo after one bend's last leaning sample to the photo before
    # the next bend's first.
    bounds = [(int(sampled[g[0]]), int(sampled[g[-1]])) for g in groups]
    edges = [-1] + [x for a, b in bounds for x in (a, b)] + [len(frames)]
    stretches = [(edges[k] + 1, edges[k + 1] - 1) for k in range(0, len(edges), 2)]
    start, end = max(stretches, key=lambda s: s[1] - s[0])
    if end < start:
        return None
    kept = list(range(start, end + 1))
    cut = [i for i in range(len(frames)) if not start <= i <= end]
    return Bend(kept=kept, cut=cut, leaning=bounds, tilts_deg=[float(tilts[k]) for g in groups for k in g])


def _together(ups: np.ndarray) -> bool:
    """Whether photos' ups (K, 3) agree with their mean within BEND_TOGETHER_DEG (median)."""
    mean = ups.mean(axis=0) / np.linalg.norm(ups.mean(axis=0))
    return bool(np.median(np.degrees(np.arccos(np.clip(ups @ mean, -1.0, 1.0)))) <= BEND_TOGETHER_DEG)


def _groups(indices: np.ndarray, gap: int) -> list[list[int]]:
    """`indices` (ascending) split where two neighbours are more than `gap` apart."""
    groups: list[list[int]] = []
    for i in indices.tolist():
        if groups and i - groups[-1][-1] <= gap:
            groups[-1].append(i)
        else:
            groups.append([i])
    return groups

