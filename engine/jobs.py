"""Progress reporting and cancellation shared by every long-running engine job.

A job takes an optional `progress` callback and an optional `CancelToken`. The CLI plugs in a
tqdm bar; Blender plugs in a queue read by a modal operator. Keeping the protocol this small lets
the same engine code serve both without knowing who is watching.
"""

from __future__ import annotations

import threading
from typing import Callable, Optional, Protocol

from .errors import Cancelled


class ProgressCallback(Protocol):
    def __call__(self, stage: str, done: int, total: int) -> None:
        """`stage` is a short human label ("features", "fusion 8 cm"); `done` of `total` steps."""


class CancelToken:
    """Thread-safe cancel flag. Jobs call `check()` between steps; it raises `Cancelled`."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def cancel(self) -> None:
        self._event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        if self._event.is_set():
            raise Cancelled()


def report(progress: Optional[ProgressCallback], stage: str, done: int, total: int) -> None:
    if progress is not None:
        progress(stage, done, total)


def check(cancel: Optional[CancelToken]) -> None:
    if cancel is not None:
        cancel.check()


class TqdmProgress:
    """A ProgressCallback that shows one tqdm bar per stage on stderr (the CLI's progress)."""

    def __init__(self, disable: bool = False) -> None:
        self._bar = None
        self._stage: Optional[str] = None
        self._disable = disable

    def __call__(self, stage: str, done: int, total: int) -> None:
        from tqdm import tqdm  # defers tqdm: only the command line's progress bar

        if stage != self._stage:
            self.close()
            self._stage = stage
            self._bar = tqdm(total=total, desc=stage, unit="step", disable=self._disable, leave=True)
        assert self._bar is not None
        if self._bar.total != total:
            self._bar.total = total
        self._bar.n = done
        self._bar.refresh()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


ProgressFn = Callable[[str, int, int], None]
