"""Functions for engine/native_worker.py's child process in tests: a crash, an abort, a hang, errors.

Module-level in a module of tests/ (on the child's PYTHONPATH, which is the parent's sys.path), so the
child imports them by name exactly as it imports the engine's own native steps.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np


def scaled(values: np.ndarray, labels: np.ndarray, factor: float) -> dict:
    """A well-behaved step: arrays and params in, arrays and numbers out."""
    return {"values": values * factor, "labels": labels[::-1], "count": len(values), "pid": os.getpid()}


def segfault(**_: object) -> dict:
    """What a native library's bad memory access does to its process."""
    os.kill(os.getpid(), signal.SIGSEGV)
    time.sleep(60)  # not reached: the signal ends the process
    return {}


def segfault_once(marker: str, **_: object) -> dict:
    """Crashes the first time (a crash that depends on thread timing), then works."""
    if not Path(marker).exists():
        Path(marker).write_text("crashed once")
        segfault()
    return {"ok": 1}


def abort(**_: object) -> dict:
    """What a failed assertion (glog CHECK, assert()) in a native library does."""
    os.abort()


def hang(pid_file: str, **_: object) -> dict:
    """A native loop that never returns (xatlas on NaN positions); writes its pid first."""
    Path(pid_file).write_text(str(os.getpid()))
    while True:
        time.sleep(0.05)


def refuses(**_: object) -> dict:
    from engine.errors import CaptureError

    raise CaptureError("photo 7.jpg is not an image: replace it")


def has_a_bug(**_: object) -> dict:
    return {"x": [][1]}


def process_is_gone(pid: int) -> bool:
    """True once `pid` no longer runs (reaped, or a zombie of another parent)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] == "Z"
    except OSError:
        return True
