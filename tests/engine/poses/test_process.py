"""The SfM worker process runner, driven by stand-in workers (no COLMAP): progress, cancel, crashes."""

from __future__ import annotations

import sys
import textwrap
import time

import pytest

from engine.errors import Cancelled, PoseError
from engine.jobs import CancelToken
from engine.poses.process import run_worker


def python(code: str) -> list[str]:
    return [sys.executable, "-u", "-c", textwrap.dedent(code)]


def test_progress_from_protocol_and_colmap_log_lines():
    calls: list[tuple[str, int, int]] = []
    run_worker(
        python(
            """
            import sys
            print("@vortx stage extract 3")
            for i in (1, 2, 3):
                print(f"I1122 04:11:33.595 1 feature_extraction.cc:270] Processed file [{i}/3]", file=sys.stderr)
            print("@vortx stage match 3")
            print("I1122 pairing.cc:214] Processing block [2/2, 1/2]", file=sys.stderr)
            print("@vortx stage map 3")
            print("I1122 incremental_pipeline.cc:620] Registering image #2 (num_reg_frames=3)", file=sys.stderr)
            print("@vortx done")
            """
        ),
        progress=lambda stage, done, total: calls.append((stage, done, total)),
    )
    assert calls == [
        ("poses: SIFT features", 0, 3),
        ("poses: SIFT features", 1, 3),
        ("poses: SIFT features", 2, 3),
        ("poses: SIFT features", 3, 3),
        ("poses: matching", 0, 3),
        ("poses: matching", 2, 4),
        ("poses: mapping", 0, 3),
        ("poses: mapping", 3, 3),
    ]


def test_cancel_kills_the_worker_promptly():
    token = CancelToken()

    def progress(stage: str, done: int, total: int) -> None:
        token.cancel()

    start = time.perf_counter()
    with pytest.raises(Cancelled):
        run_worker(python('import time; print("@vortx stage extract 5"); time.sleep(60)'), progress, token)
    assert time.perf_counter() - start < 20  # killed, not waited for


def test_an_abort_becomes_a_pose_error_with_the_log_tail():
    with pytest.raises(PoseError, match=r"(?s)SIGABRT.*Check failed: ExistsDir"):
        run_worker(python('import os; print("F1122 misc.cc:12] Check failed: ExistsDir(path)"); os.abort()'))


def test_the_workers_own_error_message_is_reported():
    with pytest.raises(PoseError, match="cannot read image /x/broken.jpg"):
        run_worker(python('import sys; print("@vortx error cannot read image /x/broken.jpg"); sys.exit(1)'))
