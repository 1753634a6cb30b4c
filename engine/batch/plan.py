"""Which captures a batch runs and where each one's outputs go."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from ..capture.detect import detect_format
from ..capture.video import VIDEO_SUFFIXES
from ..errors import CaptureError

REPORT_SUFFIX = ".report.json"


@dataclass
class CaptureJob:
    """One capture of the batch and where its outputs go."""

    capture: Path
    blend: Path
    report: Path
    export: Optional[Path] = None


def capture_name(capture: Path) -> str:
    """The output name of a capture: its folder's name (a transforms.json file: its folder's), a video's stem."""
    capture = capture.absolute()
    if capture.suffix.lower() == ".json":
        return capture.parent.name or "capture"
    return (capture.stem if capture.is_file() else capture.name) or "capture"


def plan_jobs(args: argparse.Namespace, captures: list[Path]) -> list[CaptureJob]:
    """Output paths per capture: --out itself for one .blend, else NAME.* in the --out folder (names made unique)."""
    if args.single:
        return [CaptureJob(captures[0], args.out, args.out.with_name(args.out.stem + REPORT_SUFFIX), args.export)]
    jobs, used = [], set()
    for capture in captures:
        name, n = capture_name(capture), 2
        while name in used:
            name, n = f"{capture_name(capture)}_{n}", n + 1
        used.add(name)
        export = args.out / f"{name}{args.export_suffix}" if args.export is not None else None
        jobs.append(CaptureJob(capture, args.out / f"{name}.blend", args.out / f"{name}{REPORT_SUFFIX}", export))
    return jobs


def is_capture(path: Path) -> bool:
    try:
        detect_format(path)
        return True
    except CaptureError:
        return False


def expand_captures(captures: list[Path], out: Path) -> list[Path]:
    """A single folder that is no capture itself but holds captures -> its sub-folders and capture files
    (each then gets a report; one that is no capture fails with the loader's reason). Else as given."""
    if len(captures) != 1 or not captures[0].is_dir() or is_capture(captures[0]):
        return captures
    out = out.absolute()
    candidates = sorted(p for p in captures[0].iterdir() if not p.name.startswith(".") and p.absolute() != out
                        and (p.is_dir() or p.suffix.lower() in VIDEO_SUFFIXES + (".json",)))
    detected = {p for p in candidates if is_capture(p)}
    if not detected:
        return captures  # the import then says why the folder is no capture
    return [p for p in candidates if p in detected or p.is_dir()]
