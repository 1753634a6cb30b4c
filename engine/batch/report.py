"""The batch's JSON report of one capture (NAME.report.json), the timing of its steps and the
progress line printed per finished step."""

from __future__ import annotations

import json
import os
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterator, Optional, Sequence

from ..recon.presets import quality_of
from ..recon.settings import ReconSettings
from .plan import CaptureJob


class BatchError(Exception):
    """A failure the user can act on; printed as `error: <message>`."""


def write_json_atomically(path: Path, content: Any) -> None:
    """Written under a temporary name, then renamed: a reader never sees half a report."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.partial")
    temporary.write_text(json.dumps(content, indent=1) + "\n")
    os.replace(temporary, path)


@dataclass
class CaptureReport:
    """What the batch did with one capture; written as NAME.report.json."""

    capture: str
    status: str = "failed"  # "ok" | "failed"
    error: Optional[str] = None
    failed_step: Optional[str] = None
    blend: Optional[str] = None
    export: Optional[str] = None
    capture_format: Optional[str] = None
    resolution: Optional[list[int]] = None
    frames: dict[str, Any] = field(default_factory=dict)  # loaded, posed, used, skipped (names), skip_reasons
    poses: dict[str, Any] = field(default_factory=dict)  # source, status, refined, scale_source, scale_description
    mesh: dict[str, Any] = field(default_factory=dict)  # vertices, faces, blend_bytes, export_bytes
    texture: dict[str, Any] = field(default_factory=dict)  # with --vr: the bake's settings and stats (vortx_texture)
    timings_s: dict[str, float] = field(default_factory=dict)  # per step, and total
    warnings: list[str] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    quality: Optional[str] = None  # the preset the settings match (--quality, changed by explicit flags: "custom")

    def warn(self, messages: Sequence[str]) -> None:
        self.warnings += [m for m in messages if m not in self.warnings]

    def write(self, path: Path) -> None:
        write_json_atomically(path, asdict(self))


def blank_report(job: CaptureJob, settings: ReconSettings) -> CaptureReport:
    """The report of a capture not yet run (status "failed" until it succeeds)."""
    return CaptureReport(capture=str(job.capture.absolute()), settings=asdict(settings),
                         quality=quality_of(settings) or "custom")


class StepTimer:
    """Times each step into the report and names it as the failed step when it raises."""

    def __init__(self, report: CaptureReport) -> None:
        self.report = report

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        started = time.perf_counter()
        self.report.failed_step = name
        try:
            yield
        finally:
            self.report.timings_s[name] = round(time.perf_counter() - started, 3)
        self.report.failed_step = None


def print_progress(step: int, total: int, stage: str, detail: str, started: float) -> None:
    """`vortx [step/total] stage: detail (seconds since started)`, one line per finished step."""
    print(f"vortx [{step}/{total}] {stage}: {detail} ({time.perf_counter() - started:.1f} s)", flush=True)
