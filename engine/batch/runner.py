"""The batch's loop: every capture in turn, each report written as soon as it is done; a failed
capture does not stop the others."""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path
from typing import Callable, Optional

from .plan import CaptureJob
from .report import BatchError, CaptureReport, blank_report

# Runs one capture, filling its report; raises BatchError (or anything else) on failure.
RunCapture = Callable[[CaptureJob, CaptureReport], None]


def run_jobs(args: argparse.Namespace, jobs: list[CaptureJob], run_capture: Optional[RunCapture],
             load_error: Optional[str] = None) -> int:
    """Each job through `run_capture` (None with `load_error`: the extension could not be loaded, so
    every report says why); 1 when any failed, else 0."""
    failed: list[str] = []
    for number, job in enumerate(jobs, start=1):
        if len(jobs) > 1:
            print(f"vortx capture {number}/{len(jobs)}: {job.capture}", flush=True)
        report = blank_report(job, args.settings)
        started = time.perf_counter()
        try:
            if load_error is not None:
                raise BatchError(load_error)
            if not job.capture.exists():
                raise BatchError(f"{job.capture} does not exist")
            assert run_capture is not None
            run_capture(job, report)
            report.status, report.failed_step = "ok", None
        except BatchError as error:
            report.error = str(error)
        except Exception as error:  # a bug rather than a user error: keep the traceback
            traceback.print_exc()
            report.error = f"unexpected {type(error).__name__}: {' '.join(str(error).split())}"
        report.timings_s["total"] = round(time.perf_counter() - started, 3)
        report.write(job.report)
        if report.error is not None:
            failed.append(str(job.capture))
            where = f"{job.capture}: " if len(jobs) > 1 else ""
            print(f"error: {where}{report.error}", file=sys.stderr, flush=True)
    if len(jobs) > 1:
        print(batch_summary(len(jobs), failed, args.out), flush=True)
    return 1 if failed else 0


def batch_summary(total: int, failed: list[str], reports: Path) -> str:
    """The batch's last line: how many captures were reconstructed, which failed, where the reports are."""
    return (f"vortx batch: {total - len(failed)} of {total} captures reconstructed"
            + (f"; failed: {', '.join(failed)}" if failed else "") + f"; reports in {reports}")
