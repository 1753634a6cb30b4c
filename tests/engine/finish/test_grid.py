"""A plane grid hides what lies behind it only where the views saw the plane's own surface."""

from __future__ import annotations

import numpy as np

from engine.finish.grid import PlaneGrid
from engine.finish.planes import WALL, StructuralPlane


def wall_grid(observed_columns: slice, open_cells: tuple[int, int] | None = None) -> PlaneGrid:
    """A wall at x = 0 facing +x, 4 m along y by 2.5 m up in 0.1 m cells; its surface seen in `observed_columns`
    (cells along y), every cell kept (observed or added)."""
    wall = StructuralPlane(WALL, np.array([1.0, 0.0, 0.0]), 0.0, 10.0, np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
    shape = (40, 25)
    observed = np.zeros(shape, bool)
    observed[observed_columns] = True
    opened = np.zeros(shape, bool)
    if open_cells is not None:
        opened[open_cells] = True
    return PlaneGrid(wall, np.zeros(2), 0.1, observed, np.zeros(shape, bool), np.ones(shape, bool), opened,
                     np.zeros(shape), np.zeros(shape, bool), 0.02)


def behind(y: float, z: float = 1.0) -> np.ndarray:
    return np.array([[-0.5, y, z]])  # half a metre behind the wall


def test_behind_the_seen_surface_is_hidden_behind_the_fitted_rest_is_not():
    grid = wall_grid(slice(0, 20))  # the wall's surface seen from y = 0 to 2 m; the plane fitted on to 4 m
    assert grid.blocks(behind(1.0)).all()
    assert not grid.blocks(behind(3.0)).any(), "where only the plane was fitted, nothing seen stands in front"
    assert grid.blocks(behind(2.05)).all()  # the cell next to seen surface (stereo's ragged edge)


def test_an_opening_in_the_seen_surface_hides_nothing():
    grid = wall_grid(slice(0, 40), open_cells=(slice(10, 15), slice(0, 21)))  # a door 1.0-1.5 m along, 2.1 m high
    assert not grid.blocks(behind(1.25)).any()
    assert grid.blocks(behind(3.0)).all()
