"""The matchers' stage clock: nothing is counted unless collecting; nested stages are exclusive."""

from __future__ import annotations

import pytest

from engine.stereo import stage_clock
from engine.stereo.stage_clock import collecting, phase, stage


class FakeClock:
    """A clock that moves only when told to."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_stages_are_counted_only_while_collecting_and_each_exclusive_of_its_children(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = FakeClock()
    monkeypatch.setattr(stage_clock.time, "process_time", clock)
    with stage("outside"):
        clock.now += 5.0
    totals: dict[str, float] = {}
    with collecting(totals):
        with stage("outer"):
            clock.now += 1.0
            with stage("inner"):
                clock.now += 2.0
            clock.now += 0.5
            with phase("geometric pass"):
                with stage("inner"):
                    clock.now += 4.0
        with stage("inner"):
            clock.now += 3.0
    assert totals == {"outer": 1.5, "inner": 5.0, "geometric pass/inner": 4.0}
    with stage("outside"):  # after the block: no longer counted
        clock.now += 1.0
    assert "outside" not in totals
