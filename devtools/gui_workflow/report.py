"""The GUI workflow's report.json: its steps, each step's checks and seconds, the screenshots, and
what the run measured."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any


class CheckFailed(Exception):
    """A check of the workflow failed; the run ends there."""


class WorkflowReport:
    """The report as the run fills it; `data` is what report.json holds."""

    def __init__(self, out: Path, blender: str, python: str) -> None:
        self.out = out
        self.data: dict[str, Any] = {"steps": [], "shots": [], "blender": blender, "python": python}

    def begin(self, name: str) -> None:
        self.data["steps"].append({"step": name, "checks": [], "started": time.time()})
        print(f"GUI-WORKFLOW step: {name}", flush=True)

    def check(self, condition: bool, what: str) -> None:
        """Recorded in the current step; CheckFailed when it does not hold."""
        self.data["steps"][-1]["checks"].append({"check": what, "ok": bool(condition)})
        if not condition:
            raise CheckFailed(what)

    def end(self) -> None:
        step = self.data["steps"][-1]
        step["seconds"] = round(time.time() - step.pop("started"), 1)

    def add_shot(self, path: Path, what: str) -> None:
        self.data["shots"].append({"file": path.name, "what": what, "bytes": path.stat().st_size})

    def finish(self, ok: bool, error: str = "") -> None:
        """Write <out>/report.json and say how the run ended (the failed step keeps the error)."""
        self.data["ok"] = ok
        if error:
            self.data["error"] = error
            if self.data["steps"]:
                self.data["steps"][-1]["error"] = error
                self.data["steps"][-1].pop("started", None)
        (self.out / "report.json").write_text(json.dumps(self.data, indent=1))
        print(f"GUI-WORKFLOW {'OK' if ok else 'FAILED: ' + error}", flush=True)
