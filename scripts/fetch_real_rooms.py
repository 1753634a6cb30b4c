"""Fetch the real-room suite's captures into a data folder (never into this repository).

    .venv/bin/python scripts/fetch_real_rooms.py [DATA_DIR] [--mirror DIR]

DATA_DIR defaults to ../data beside the checkout, where `python -m engine bench --real` looks. Each
room of engine/eval/real_rooms_manifest.json with a source is taken from its public repository at the
pinned commit (`git archive`), the files the manifest excludes left out (large files the rooms do not
need), and prepared where the manifest says so (SUN3D: scripts/sun3d_room.py's conversion). A room
already there is left alone. `--mirror DIR` reads the repositories from local git directories
(DIR/<owner>+<name>/repo, or DIR/<owner>+<name>) instead of cloning them from GitHub. Each capture
keeps its own licence (the manifest names it): research and testing use.
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path
from typing import Optional

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from engine.data.sun3d import convert_sun3d  # noqa: E402
from engine.eval.real_rooms import DEFAULT_DATA, MANIFEST, room_path  # noqa: E402


def git_dir(repo: str, mirror: Optional[Path], scratch: Path) -> Path:
    """A git directory holding `repo` ("owner/name"): the local mirror's, else a blobless clone."""
    if mirror is not None:
        for folder in (mirror / repo.replace("/", "+") / "repo", mirror / repo.replace("/", "+")):
            for candidate in (folder / ".git", folder):  # a clone with a work tree, or a bare one
                if (candidate / "objects").is_dir():
                    return candidate
        raise SystemExit(f"error: no git directory for {repo} under {mirror}")
    target = scratch / repo.replace("/", "+")
    subprocess.run(["git", "clone", "--quiet", "--bare", "--filter=blob:none", f"https://github.com/{repo}.git",
                    str(target)], check=True)
    return target


def extract(git: Path, source: dict, into: Path) -> None:
    """`source["path"]` at `source["commit"]` into `into`, its first `strip` folders dropped."""
    excluded = [f":(exclude){path}" for path in source.get("exclude", [])]
    archive = subprocess.run(["git", f"--git-dir={git}", "archive", "--format=tar", source["commit"], "--",
                              source["path"], *excluded], capture_output=True, check=True).stdout
    into.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        for member in tar.getmembers():
            parts = Path(member.name).parts[source.get("strip", 0):]
            if not parts or member.issym() or member.islnk() or ".." in parts:
                continue
            member.name = str(Path(*parts))
            tar.extract(member, into, filter="data")


def fetch(data: Path, mirror: Optional[Path]) -> int:
    rooms = json.loads(MANIFEST.read_text())["rooms"]
    with tempfile.TemporaryDirectory() as scratch_dir:
        scratch = Path(scratch_dir)
        for room in rooms:
            source = room.get("source")
            target = room_path(room["folder"], data)
            if source is None:
                print(f"{room['name']}: {'here' if target.exists() else 'not here'} ({target}; not fetched)")
                continue
            if target.exists():
                print(f"{room['name']}: already at {target}")
                continue
            print(f"{room['name']}: fetching {source['repo']} at {source['commit']}, {source['path']} "
                  f"(licence: {room['licence']})", flush=True)
            git = git_dir(source["repo"], mirror, scratch)
            if source.get("prepare") == "sun3d":
                raw = scratch / f"{room['name']}-source"
                extract(git, source, raw)
                convert_sun3d(raw, target)
            else:
                extract(git, source, target if source.get("strip", 0) else data)
            print(f"{room['name']}: at {target}")
    return 0


def main(argv: Optional[list[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path, nargs="?", default=DEFAULT_DATA, help="the data folder (default %(default)s)")
    parser.add_argument("--mirror", type=Path, default=None, help="local git directories instead of GitHub")
    args = parser.parse_args(argv)
    return fetch(args.data, args.mirror)


if __name__ == "__main__":
    sys.exit(main())
