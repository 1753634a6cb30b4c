"""The demo's own checks and commands (devtools/demo/pipeline.py); `make demo` runs the whole."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pytest

from devtools.demo import pipeline
from devtools.demo.messages import DemoError


def options(sample: Path, **given) -> argparse.Namespace:
    return argparse.Namespace(sample=sample, weights=given.get("weights"), method=given.get("method", "stereo"),
                              compare=given.get("compare", True))


def test_an_incomplete_sample_or_missing_weights_stop_the_demo_before_it_runs(tmp_path: Path, monkeypatch) -> None:
    with pytest.raises(DemoError, match="the demo sample is incomplete .* scripts/make_demo_sample.py"):
        pipeline.check_sample(options(tmp_path))
    (tmp_path / "images").mkdir()
    (tmp_path / "truth").mkdir()
    (tmp_path / "truth" / "mesh_gt.ply").write_text("ply")
    pipeline.check_sample(options(tmp_path))
    monkeypatch.setattr(pipeline, "DEFAULT_WEIGHTS", pipeline.REPO / "weights" / "absent.safetensors")
    with pytest.raises(DemoError, match=r"weights/absent.safetensors\); `scripts/demo.py --weights random`"):
        pipeline.check_sample(options(tmp_path))
    pipeline.check_sample(options(tmp_path, compare=False))  # stereo alone needs no weights
    pipeline.check_sample(options(tmp_path, weights="random"))


def test_weights_go_only_to_the_method_that_reads_them() -> None:
    assert pipeline.weights_flag("random", "vortx") == ["--weights", "random"]
    assert pipeline.weights_flag("random", "stereo") == [] and pipeline.weights_flag(None, "vortx") == []


def test_a_failing_tool_stops_the_demo_with_its_step(monkeypatch, capsys) -> None:
    monkeypatch.setattr(sys, "executable", "false")  # any command fails
    with pytest.raises(DemoError, match=r"^texturing out/demo.ply failed \(its error is above\)$"):
        pipeline.run_engine(["texture", "posed", "out/demo.ply"], "texturing out/demo.ply")
    assert capsys.readouterr().out == "demo: running -m engine texture posed out/demo.ply\n"
