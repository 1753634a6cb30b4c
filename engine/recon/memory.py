"""Peak memory of a run: a sampler of this process's resident set size, and CUDA's own counter.

`resource.getrusage(...).ru_maxrss` is the peak of the whole process's life, so a second run in the
same process (the benchmark, Blender) would report the first run's peak. A background thread that
samples the current RSS from /proc gives the peak of this run alone; both are recorded.
"""

from __future__ import annotations

import os
import resource
import sys
import threading
from typing import Optional

import torch

PAGE_SIZE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def current_rss_bytes() -> Optional[int]:
    """This process's resident set size now; None where /proc is unavailable (macOS, Windows)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * PAGE_SIZE
    except OSError:
        return None


def process_max_rss_bytes() -> int:
    """Peak RSS over the process's whole life (getrusage: kilobytes on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


class PeakMemory:
    """Context manager: samples RSS every `interval` seconds while the block runs.

    After the block: `peak_rss` (bytes, this block only; falls back to the process peak without
    /proc), `start_rss`, `cuda_peak` (bytes allocated by torch on `device`, or None).
    """

    def __init__(self, device: Optional[torch.device] = None, interval: float = 0.02) -> None:
        self.device = device
        self.interval = interval
        self.start_rss: Optional[int] = None
        self.peak_rss: int = 0
        self.cuda_peak: Optional[int] = None
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    def _sample(self) -> None:
        while not self._stop.wait(self.interval):
            rss = current_rss_bytes()
            if rss is not None and rss > self.peak_rss:
                self.peak_rss = rss

    def __enter__(self) -> "PeakMemory":
        self.start_rss = current_rss_bytes()
        self.peak_rss = self.start_rss or 0
        if self.device is not None and self.device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(self.device)
        self._thread = threading.Thread(target=self._sample, name="vortx-rss-sampler", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        rss = current_rss_bytes()
        if rss is None:
            self.peak_rss = process_max_rss_bytes()
        else:
            self.peak_rss = max(self.peak_rss, rss)
        if self.device is not None and self.device.type == "cuda":
            self.cuda_peak = int(torch.cuda.max_memory_allocated(self.device))

    def to_dict(self) -> dict[str, Optional[int]]:
        return {
            "peak_rss_bytes": self.peak_rss,
            "start_rss_bytes": self.start_rss,
            "process_max_rss_bytes": process_max_rss_bytes(),
            "cuda_max_allocated_bytes": self.cuda_peak,
        }
