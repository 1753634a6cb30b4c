"""The walking loop of a synthetic room's camera path (pure numpy).

`room.py` draws one per room (`RoomSpec.path`, kept clear of furniture) and `trajectory.py` walks it;
it lives here, below both, so the room description and the camera path import one way
(path_loop <- room <- trajectory).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class PathLoop:
    """A closed walking loop: a superellipse around `center` with radial wobble (all in metres)."""

    center: list[float]
    semi_axes: list[float]
    exponent: float  # 2 = ellipse, larger = closer to a rectangle
    wobble: list[list[float]] = field(default_factory=list)  # (harmonic k, amplitude, phase)

    def sample(self, n: int = 512) -> np.ndarray:
        """(n, 2) points along the loop, counter-clockwise, starting at angle 0."""
        t = np.linspace(0, 2 * np.pi, n, endpoint=False)
        c, s = np.cos(t), np.sin(t)
        e = 2.0 / self.exponent
        radial = 1.0 + sum(a * np.cos(k * t + ph) for k, a, ph in self.wobble)
        x = self.semi_axes[0] * np.sign(c) * np.abs(c) ** e * radial
        y = self.semi_axes[1] * np.sign(s) * np.abs(s) ** e * radial
        return np.stack([x + self.center[0], y + self.center[1]], axis=1)

    @property
    def points(self) -> np.ndarray:
        return self.sample()


def make_path_loop(rng: np.random.Generator, length: float, width: float) -> PathLoop:
    """A loop about 0.9-1.4 m from the walls (closer in small rooms, never under 0.25 m semi-axis)."""
    half = np.array([length, width]) / 2
    margin = np.minimum(rng.uniform(0.9, 1.4, 2), half - 0.25)
    center = half + rng.uniform(-0.15, 0.15, 2) * (half - margin - 0.2).clip(0, None)
    wobble = [[float(k), float(rng.uniform(0.0, 0.06)), float(rng.uniform(0, 2 * np.pi))] for k in (2, 3)]
    return PathLoop([float(c) for c in center], [float(a) for a in half - margin], float(rng.uniform(2.5, 4.0)), wobble)
