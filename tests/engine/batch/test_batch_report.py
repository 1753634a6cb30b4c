"""The batch's report of one capture (engine/batch/report.py): what NAME.report.json holds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine.batch.plan import CaptureJob
from engine.batch.report import StepTimer, blank_report, write_json_atomically
from engine.recon.presets import apply_quality
from engine.recon.settings import ReconSettings


def job(tmp_path: Path) -> CaptureJob:
    return CaptureJob(tmp_path / "kitchen", tmp_path / "kitchen.blend", tmp_path / "out" / "kitchen.report.json")


def test_a_new_report_is_failed_with_the_settings_and_their_preset(tmp_path: Path) -> None:
    report = blank_report(job(tmp_path), ReconSettings(stereo_views=7))
    assert report.status == "failed" and report.capture == str((tmp_path / "kitchen").absolute())
    assert report.settings["stereo_views"] == 7 and report.quality == "custom"  # no preset has 7 views
    assert blank_report(job(tmp_path), apply_quality(ReconSettings(), "preview")).quality == "preview"


def test_the_report_is_written_whole_and_a_warning_given_again_is_kept_once(tmp_path: Path) -> None:
    report = blank_report(job(tmp_path), ReconSettings())
    report.warn(["blurry photo 3"])
    report.warn(["blurry photo 3", "no EXIF"])
    report.write(job(tmp_path).report)
    written = json.loads(job(tmp_path).report.read_text())
    assert written["warnings"] == ["blurry photo 3", "no EXIF"] and written["status"] == "failed"
    assert [p.name for p in job(tmp_path).report.parent.iterdir()] == ["kitchen.report.json"]  # no partial file left
    write_json_atomically(job(tmp_path).report, {"replaced": True})
    assert json.loads(job(tmp_path).report.read_text()) == {"replaced": True}


def test_a_step_is_timed_and_named_as_the_failed_one_when_it_raises(tmp_path: Path) -> None:
    report = blank_report(job(tmp_path), ReconSettings())
    step = StepTimer(report)
    with step("import capture"):
        assert report.failed_step == "import capture"
    assert report.failed_step is None
    with pytest.raises(RuntimeError), step("poses"):
        raise RuntimeError("no pose")
    assert report.failed_step == "poses" and set(report.timings_s) == {"import capture", "poses"}
