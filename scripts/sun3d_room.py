"""Convert the SUN3D study-room sample of the 3DMatch toolbox into a development room with ground truth.

    .venv/bin/python scripts/sun3d_room.py SOURCE OUT

SOURCE: a local copy of `data/sample/depth-fusion-demo` of andyzeng/3dmatch-toolbox at commit
4b4a3687 (the commit that added the 100 study-room frames; later commits replaced them). It is
research data under its own licence: keep it out of this repository. OUT: a new room folder that
`engine eval-weights --rooms`, `engine eval-depth` and `engine reconstruct` read (see
engine/data/sun3d.py for what goes where). Tests that use it look at $VORTX_SUN3D_ROOM.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from engine.data.sun3d import convert_sun3d  # noqa: E402
from engine.errors import VortxError  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("source", type=Path, help="the depth-fusion-demo folder of the 3DMatch toolbox (commit 4b4a3687)")
    parser.add_argument("out", type=Path, help="a new folder for the room")
    args = parser.parse_args(argv)
    try:
        summary = convert_sun3d(args.source, args.out)
    except VortxError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
