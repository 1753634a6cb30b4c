"""`make demo`: the whole product on the bundled sample capture, checked against the sample's truth.

    .venv/bin/python scripts/demo.py [--method stereo|vortx] [--weights PATH|random] [--device cpu|cuda]
                                     [--sample samples/demo_room] [--no-compare]

Runs the batch on the sample's photos, scores the estimated poses and the meshes (both methods and
a plain room box) against the sample's truth, textures the result and measures it from held-out
photos, and writes pictures of each into out/. The steps: devtools/demo/ (its __init__ lists them).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional, Sequence

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from _extension_dev import vortx_extension  # noqa: E402  (scripts/ is not a package)
from devtools.demo.messages import DemoError  # noqa: E402
from devtools.demo.pipeline import run_demo  # noqa: E402
from engine.recon.settings import METHODS, ReconSettings  # noqa: E402


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sample", type=Path, default=REPO / "samples" / "demo_room", help="sample folder with images/ and truth/")
    parser.add_argument("--out-dir", type=Path, default=REPO / "out")
    parser.add_argument("--weights", help="weights file or 'random' (default: the shipped weights/vortx-default.safetensors)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument("--method", choices=METHODS, default=ReconSettings().method,
                        help="method of the main run (default: the product's default, %(default)s)")
    parser.add_argument("--no-compare", dest="compare", action="store_false",
                        help="skip reconstructing with the other method for the side-by-side table")
    args = parser.parse_args(argv)
    try:
        run_demo(args, vortx_extension)
    except DemoError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
