"""The GUI workflow's report.json (devtools/gui_workflow/report.py): steps, checks, shots, the end."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from devtools.gui_workflow.report import CheckFailed, WorkflowReport


def test_a_run_records_each_step_its_checks_and_shots(tmp_path: Path, capsys) -> None:
    report = WorkflowReport(tmp_path, "4.3.2", "3.13.1")
    report.begin("Import Capture")
    report.check(True, "Import Capture finished")
    (tmp_path / "gui_02_imported.png").write_bytes(b"x" * 10)
    report.add_shot(tmp_path / "gui_02_imported.png", "Capture panel after Import Capture")
    report.end()
    report.data["posed"] = 36
    report.finish(True)
    written = json.loads((tmp_path / "report.json").read_text())
    (step,) = written["steps"]
    assert step["step"] == "Import Capture" and step["checks"] == [{"check": "Import Capture finished", "ok": True}]
    assert "started" not in step and step["seconds"] >= 0
    assert written["shots"] == [{"file": "gui_02_imported.png", "what": "Capture panel after Import Capture", "bytes": 10}]
    assert written["ok"] and written["posed"] == 36 and written["blender"] == "4.3.2" and written["python"] == "3.13.1"
    assert capsys.readouterr().out == "GUI-WORKFLOW step: Import Capture\nGUI-WORKFLOW OK\n"


def test_a_failed_check_ends_the_run_and_names_the_step(tmp_path: Path, capsys) -> None:
    report = WorkflowReport(tmp_path, "4.3.2", "3.13.1")
    report.begin("Estimate Poses")
    with pytest.raises(CheckFailed, match="most photos are posed"):
        report.check(False, "most photos are posed (3 of 36)")
    report.finish(False, "check failed: most photos are posed (3 of 36)")
    written = json.loads((tmp_path / "report.json").read_text())
    assert not written["ok"] and written["error"] == written["steps"][-1]["error"]
    assert written["steps"][-1]["checks"] == [{"check": "most photos are posed (3 of 36)", "ok": False}]
    assert "started" not in written["steps"][-1]
    assert capsys.readouterr().out.endswith("GUI-WORKFLOW FAILED: check failed: most photos are posed (3 of 36)\n")
