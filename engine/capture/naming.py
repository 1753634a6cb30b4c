"""How frame files are ordered and how lists of names appear in messages.

Photos are named by cameras and exporters with unpadded counters (`frame2.jpg`, `frame10.jpg`), so a
plain string sort would shuffle the sequence; every loader orders files with `natural_key`.
"""

from __future__ import annotations

import re
from typing import Iterable

_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple:
    """Sort key that compares digit runs as numbers: "frame2" < "frame10" < "Frame11".

    `re.split` with a capture group alternates text and digits starting with text, so position i
    always holds the same kind of value and ints are never compared with strings. The original
    name is the final tie-breaker ("a01" vs "a1") so the order is total and stable.
    """
    parts = _DIGITS.split(name)
    key = tuple(int(part) if i % 2 else part.lower() for i, part in enumerate(parts))
    return (key, name)


def name_list(names: Iterable[str], limit: int = 20) -> str:
    """"a, b and c" for messages; after `limit` names, "... and N more" keeps warnings readable."""
    names = list(names)
    if len(names) <= limit:
        if len(names) <= 1:
            return "".join(names)
        return ", ".join(names[:-1]) + " and " + names[-1]
    return ", ".join(names[:limit]) + f" and {len(names) - limit} more"
