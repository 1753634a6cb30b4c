"""Folders for files the loaders derive from a capture (video frames, undistorted photos).

Default location: the per-user cache, `<user cache>/vortx/<capture folder name>-<hash of its
path>/<name>/`, where <user cache> is `%LOCALAPPDATA%` on Windows, `~/Library/Caches` on macOS and
`$XDG_CACHE_HOME` or `~/.cache` elsewhere (the system temporary folder when that is not writable).
Not next to the photos: capture folders are often read-only, shared, or synced to a cloud drive
that would upload hundreds of megabytes of derived images. `cache_dir=` (CLI `--cache-dir`)
overrides the location; deleting the folder is always safe.

A folder is reused only when its `manifest.json` records the same key (source file sizes and
modification times plus the parameters that produced it); otherwise its old contents are deleted
and it is rebuilt. The manifest is written last, so an interrupted run is never mistaken for a
finished one.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any, Optional

from ..errors import CaptureError

_MANIFEST = "manifest.json"


def _user_cache_root() -> Path:
    if sys.platform == "win32":
        return Path(os.environ.get("LOCALAPPDATA", Path.home() / "AppData" / "Local")) / "vortx"
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "vortx"
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "vortx"


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
        return True
    except OSError:
        return False


def cache_folder(capture_folder: Path, name: str, cache_dir: Optional[Path] = None) -> Path:
    """The folder for files derived from `capture_folder` called `name` (e.g. "video-walk-2fps"),
    created if needed."""
    if cache_dir is not None:
        candidates = [Path(cache_dir) / name]
    else:
        absolute = capture_folder.absolute()
        digest = hashlib.sha1(str(absolute).encode()).hexdigest()[:10]
        capture_key = f"{absolute.name or 'capture'}-{digest}"
        candidates = [_user_cache_root() / capture_key / name,
                      Path(tempfile.gettempdir()) / "vortx" / capture_key / name]
    for folder in candidates:
        if _writable(folder):
            return folder
    raise CaptureError(f"no writable folder for derived images: tried {', '.join(map(str, candidates))}. "
                       "Pass a writable cache_dir (CLI: --cache-dir).")


def source_stamp(paths: list[Path]) -> list[list[Any]]:
    """Identifies the source files' versions cheaply: [name, size, mtime_ns] per file."""
    stamp = []
    for path in paths:
        stat = path.stat()
        stamp.append([str(path), stat.st_size, stat.st_mtime_ns])
    return stamp


def read_manifest(folder: Path, key: dict[str, Any]) -> Optional[dict[str, Any]]:
    """The manifest's `result` when the folder was completed for exactly this `key`, else None."""
    try:
        manifest = json.loads((folder / _MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    if manifest.get("key") != json.loads(json.dumps(key)):  # round-trip: tuples vs lists
        return None
    return manifest.get("result")


def reset_folder(folder: Path) -> None:
    """Empty `folder` before rebuilding it (it only ever holds files this package wrote)."""
    for child in folder.iterdir():
        if child.is_dir():
            shutil.rmtree(child)
        else:
            child.unlink()


def write_manifest(folder: Path, key: dict[str, Any], result: dict[str, Any]) -> None:
    (folder / _MANIFEST).write_text(json.dumps({"key": key, "result": result}, indent=1))
