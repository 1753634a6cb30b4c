"""Zipped captures (a phone app's export shared as .zip, Record3D's .r3d): unpacked once into the
cache (`cache.py`), then loaded like the folder they hold.

Members are data: absolute paths, `..` components and links are refused (a crafted zip must not
write outside its cache folder), and the unpacked size is capped.
"""

from __future__ import annotations

import zipfile
from pathlib import Path, PurePosixPath
from typing import Optional

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn, check, report
from .cache import cache_folder, read_manifest, reset_folder, source_stamp, write_manifest

ARCHIVE_SUFFIXES = (".zip", ".r3d")
MAX_UNPACKED_BYTES = 20 * 1024 ** 3  # a phone capture is a few GB at most; more is a mistake or a zip bomb


def is_archive(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in ARCHIVE_SUFFIXES


def unpacked_archive(path: Path, cache_dir: Optional[Path] = None, progress: Optional[ProgressFn] = None,
                     cancel: Optional[CancelToken] = None) -> Path:
    """The folder holding `path`'s contents (unpacked on first use, reused while the file is unchanged);
    when the archive holds a single top folder, that folder. CaptureError naming the file when it is
    not a readable zip or a member would land outside the folder."""
    folder = cache_folder(path.parent, f"unpacked-{path.name}", cache_dir)
    key = {"version": 1, "source": source_stamp([path])}
    if read_manifest(folder, key) is None:
        reset_folder(folder)
        _unpack(path, folder, progress, cancel)
        write_manifest(folder, key, {})
    entries = [p for p in folder.iterdir() if p.name != "manifest.json" and not p.name.startswith((".", "__MACOSX"))]
    return entries[0] if len(entries) == 1 and entries[0].is_dir() else folder


def _unpack(path: Path, folder: Path, progress: Optional[ProgressFn], cancel: Optional[CancelToken]) -> None:
    try:
        archive = zipfile.ZipFile(path)
    except (OSError, zipfile.BadZipFile) as error:
        raise CaptureError(f"{path} is not a readable zip archive ({error}): copy the export again from the phone, "
                           "or unpack it yourself and choose the folder.") from error
    with archive:
        members = archive.infolist()
        total = sum(m.file_size for m in members)
        if total > MAX_UNPACKED_BYTES:
            raise CaptureError(f"{path} would unpack to {total / 1024 ** 3:.1f} GB, more than the "
                               f"{MAX_UNPACKED_BYTES / 1024 ** 3:.0f} GB a capture may have: unpack it yourself.")
        for i, member in enumerate(members):
            check(cancel)
            report(progress, "unpacking the capture", i, len(members))
            name = PurePosixPath(member.filename.replace("\\", "/"))
            is_link = (member.external_attr >> 16) & 0o170000 == 0o120000
            if name.is_absolute() or ".." in name.parts or is_link:
                raise CaptureError(f"{path} holds {member.filename!r}, which would be written outside the folder it "
                                   "unpacks to: the archive is not a capture export; it was not unpacked.")
            if member.is_dir():
                continue
            target = folder.joinpath(*name.parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                with archive.open(member) as source, open(target, "wb") as sink:
                    while chunk := source.read(1 << 20):
                        sink.write(chunk)
            except (OSError, zipfile.BadZipFile, EOFError) as error:
                raise CaptureError(f"cannot unpack {member.filename} from {path} ({error}): the archive is damaged; "
                                   "copy it again from the phone.") from error
        report(progress, "unpacking the capture", len(members), len(members))
