"""The batch's loop over captures (engine/batch/runner.py): a failed capture does not stop the
others, each gets its report, and the exit status says whether any failed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine.batch.arguments import parse_arguments
from engine.batch.plan import CaptureJob, plan_jobs
from engine.batch.report import BatchError, CaptureReport
from engine.batch.runner import run_jobs


@pytest.fixture
def rooms(tmp_path: Path) -> list[Path]:
    folders = [tmp_path / name for name in ("kitchen", "hall", "attic")]
    for folder in folders:
        folder.mkdir()
    return folders


def read(job: CaptureJob) -> dict:
    return json.loads(job.report.read_text())


def test_each_capture_is_reported_and_a_failure_does_not_stop_the_others(rooms, tmp_path, capsys) -> None:
    args = parse_arguments([*map(str, rooms), str(tmp_path / "missing"), "--out", str(tmp_path / "out")])
    jobs = plan_jobs(args, args.captures)

    def run_capture(job: CaptureJob, report: CaptureReport) -> None:
        report.timings_s["reconstruct"] = 1.0
        if job.capture.name == "hall":
            report.failed_step = "poses"
            raise BatchError("no frame has a pose")
        if job.capture.name == "attic":
            raise KeyError("a bug")

    assert run_jobs(args, jobs, run_capture) == 1
    kitchen, hall, attic, missing = map(read, jobs)
    assert kitchen["status"] == "ok" and kitchen["failed_step"] is None and set(kitchen["timings_s"]) == {"reconstruct", "total"}
    assert hall["status"] == "failed" and hall["failed_step"] == "poses" and hall["error"] == "no frame has a pose"
    assert attic["error"] == "unexpected KeyError: 'a bug'"
    assert missing["error"] == f"{tmp_path / 'missing'} does not exist"
    out, err = capsys.readouterr()
    assert "vortx capture 2/4: " in out and "Traceback" in err and f"error: {rooms[1]}: no frame has a pose" in err
    assert out.splitlines()[-1] == (f"vortx batch: 1 of 4 captures reconstructed; failed: {rooms[1]}, {rooms[2]}, "
                                    f"{tmp_path / 'missing'}; reports in {tmp_path / 'out'}")


def test_an_extension_that_did_not_load_fails_every_capture_with_its_reason(rooms, tmp_path, capsys) -> None:
    args = parse_arguments([str(rooms[0]), "--out", str(tmp_path / "scene.blend")])
    jobs = plan_jobs(args, args.captures)
    assert run_jobs(args, jobs, None, load_error="could not enable the extension") == 1
    assert read(jobs[0])["error"] == "could not enable the extension" and jobs[0].report == tmp_path / "scene.report.json"
    assert capsys.readouterr().err == "error: could not enable the extension\n"  # one capture: no name, no summary


def test_all_captures_done_exits_zero(rooms, tmp_path) -> None:
    args = parse_arguments([str(rooms[0]), "--out", str(tmp_path / "scene.blend")])
    assert run_jobs(args, plan_jobs(args, args.captures), lambda job, report: None) == 0
