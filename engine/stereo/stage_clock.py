"""Seconds spent in each stage of a matcher, collected only when asked for (`engine bench
--patchmatch-profile`), so the matchers can say where their time goes without a profiler's overhead.

`stage(name)` marks a block; stages nest and each is timed exclusively (a child's time is not also
counted in its parent), so the totals add up to the time inside the outermost stages. Outside
`collecting` a stage costs one global lookup.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Callable, Iterator, Optional

import torch

_totals: Optional[dict[str, float]] = None
_stack: list[list] = []  # [name, start] of the open stages, innermost last
_clock: Callable[[], float] = time.process_time
_phase = ""  # prefixed to the stage names: "geometric pass/sampling"


@contextmanager
def collecting(totals: dict[str, float], device: Optional[torch.device] = None) -> Iterator[dict[str, float]]:
    """Add the seconds of every stage run inside this block to `totals` (name -> seconds). On the CPU
    the clock is the process's CPU time (the shared machine's load does not inflate it); on CUDA the
    wall clock after synchronising the device, since the kernels run asynchronously."""
    global _totals, _clock
    previous, previous_clock = _totals, _clock
    if device is not None and device.type == "cuda":
        def wall() -> float:
            torch.cuda.synchronize(device)
            return time.perf_counter()
        _clock = wall
    else:
        _clock = time.process_time
    _totals = totals
    try:
        yield totals
    finally:
        _totals, _clock = previous, previous_clock
        _stack.clear()


def collecting_now() -> bool:
    """Whether stages are being timed (the clock keeps one stack: callers then run on one thread)."""
    return _totals is not None


@contextmanager
def stage(name: str) -> Iterator[None]:
    """Time the block as stage `name` (exclusive of the stages nested in it) while collecting."""
    if _totals is None:
        yield
        return
    now = _clock()
    if _stack:
        parent = _stack[-1]
        _totals[parent[0]] = _totals.get(parent[0], 0.0) + now - parent[1]
    _stack.append([_phase + name, now])
    try:
        yield
    finally:
        now = _clock()
        own = _stack.pop()
        if _totals is not None:
            _totals[own[0]] = _totals.get(own[0], 0.0) + now - own[1]
        if _stack:
            _stack[-1][1] = now


@contextmanager
def phase(name: str) -> Iterator[None]:
    """The stages inside this block are counted as "name/stage" (e.g. the geometric pass's own sampling)."""
    global _phase
    previous = _phase
    _phase = f"{name}/"
    try:
        yield
    finally:
        _phase = previous
