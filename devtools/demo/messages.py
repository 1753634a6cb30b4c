"""How the demo talks: `demo: ...` lines as it goes, DemoError for what stops it."""

from __future__ import annotations


class DemoError(Exception):
    """The demo cannot go on; printed as `error: <message>` (exit status 1)."""


def say(message: str) -> None:
    print(f"demo: {message}", flush=True)
