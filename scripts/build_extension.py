"""Build the installable extension zip with Blender's own builder (`make extension`).

    .venv/bin/python scripts/build_extension.py [--output-dir dist]   ->  dist/vortx-<version>.zip

Runs `blender_ext.py build --source-dir <checkout> --output-dir <dir>` from the bpy package (the
script `blender --command extension build` forwards to; it validates the manifest and applies its
[build] excludes, blender-notes.md section 1). No `blender` binary is needed, and bpy is not
imported: the builder is found on disk.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Optional, Sequence

CHECKOUT = Path(__file__).resolve().parent.parent
BUILDER = Path("scripts") / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"


class BuildError(Exception):
    pass


def blender_ext_script() -> Path:
    """blender_ext.py inside the installed bpy package (bpy/<version>/scripts/addons_core/...)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        raise BuildError("the bpy module is not installed in this Python; run `make venv` first")
    candidates = sorted(Path(spec.origin).parent.glob(f"*/{BUILDER.as_posix()}"))
    if not candidates:
        raise BuildError(f"Blender's extension builder ({BUILDER}) is not in {Path(spec.origin).parent}")
    return candidates[-1]


def archive_name(source: Path) -> str:
    manifest = tomllib.loads((source / "blender_manifest.toml").read_text(encoding="utf-8"))
    return f"{manifest['id']}-{manifest['version']}.zip"


def build(source: Path = CHECKOUT, output_dir: Path = CHECKOUT / "dist", python: str = sys.executable) -> Path:
    """Build the zip into `output_dir` (created) and return its path; BuildError with the builder's output."""
    output_dir.mkdir(parents=True, exist_ok=True)
    archive = output_dir / archive_name(source)
    archive.unlink(missing_ok=True)  # the builder refuses nothing, but a stale zip must not pass for a new one
    command = [python, str(blender_ext_script()), "build", "--source-dir", str(source), "--output-dir", str(output_dir)]
    run = subprocess.run(command, capture_output=True, text=True)
    # The builder can print ERROR and still exit 0 (blender-notes.md section 1), so check both.
    if run.returncode != 0 or "ERROR" in run.stdout + run.stderr or not archive.is_file():
        raise BuildError(f"the extension build failed:\n{run.stdout}{run.stderr}".rstrip())
    return archive


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output-dir", type=Path, default=CHECKOUT / "dist", help="where the zip goes (default: dist/)")
    args = parser.parse_args(argv)
    try:
        archive = build(CHECKOUT, args.output_dir.resolve())
    except BuildError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    print(f"built {archive} ({archive.stat().st_size / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
