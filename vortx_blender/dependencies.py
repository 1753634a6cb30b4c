"""The Python packages the engine needs inside Blender: which are missing, and installing them.

Blender ships Python and numpy but not torch, OpenCV, Pillow, pycolmap, scikit-image or safetensors.
The extension registers without them (the engine imports them inside jobs only); the preferences
list what is missing and one button installs the pinned versions into the extension's user folder
`bpy.utils.extension_path_user(<package>, path="site-packages")`, which survives extension updates
(the extension's own folder is wiped on update) and is removed on uninstall (blender-notes.md
section 2). That folder is put on sys.path at register.

The pins come from one place: requirements.txt (the direct dependencies), then constraints.txt (every
transitive version of the tested .venv); both ship in the extension zip.

numpy is never installed: a second numpy on sys.path would shadow or clash with the one Blender's
own modules were built against. pip cannot exclude a package from a resolution, so installing is
two pip runs: `pip install --dry-run --report` resolves the full set for this Python and platform
(numpy held at Blender's version), then `pip install --target --no-deps` installs that set minus
numpy.

This module does not import bpy at module level and is runnable as a script, which is the manual
install command shown when Blender's online access is off:
    "<blender python>" ".../vortx_blender/dependencies.py" --target "<site-packages folder>"
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import importlib.util
import json
import os
import queue
import re
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Optional, Protocol, Sequence

if __package__:
    from ..engine.errors import Cancelled, VortxError
else:  # run as a script (the manual install command): no package around this file

    class VortxError(Exception):  # type: ignore[no-redef]
        pass

    class Cancelled(VortxError):  # type: ignore[no-redef]
        pass


EXTENSION_ROOT = Path(__file__).resolve().parent.parent
REQUIREMENTS_FILE = EXTENSION_ROOT / "requirements.txt"
CONSTRAINTS_FILE = EXTENSION_ROOT / "constraints.txt"
SITE_PACKAGES = "site-packages"  # the folder name under extension_path_user

# Import name -> distribution, for everything the engine imports inside Blender jobs: loading
# captures (cv2, PIL), structure from motion (pycolmap), the network (torch, safetensors), marching
# cubes (skimage), the texture bake's UV atlas (xatlas) and the VR preset's decimation
# (fast_simplification). Training/CLI-only packages (tqdm, efficientnet weights, scipy for eval) are not here.
RUNTIME_MODULES: dict[str, str] = {
    "torch": "torch",
    "cv2": "opencv-python-headless",
    "PIL": "pillow",
    "pycolmap": "pycolmap",
    "skimage": "scikit-image",
    "safetensors": "safetensors",
    "xatlas": "xatlas",
    "fast_simplification": "fast-simplification",
}
# Distributions Blender itself provides; never installed, whatever the resolver says.
BLENDER_PROVIDED: frozenset[str] = frozenset({"numpy"})

PIP_QUIET_FLAGS = ("--no-input", "--disable-pip-version-check", "--progress-bar", "off")


class DependencyError(VortxError):
    """Installing or checking the engine's Python packages failed; the message says what to do."""


class ProgressFn(Protocol):
    def __call__(self, stage: str, done: int, total: int) -> None: ...


class CancelFlag(Protocol):
    @property
    def cancelled(self) -> bool: ...


def canonical_name(name: str) -> str:
    """PEP 503 normalised distribution name ("Pillow", "scikit_image" -> "pillow", "scikit-image")."""
    return re.sub(r"[-_.]+", "-", name).lower()


# ------------------------------------------------------------------------------------------ pins


def read_pins(path: Path) -> dict[str, str]:
    """`name==version` lines of a requirements/constraints file -> {canonical name: version}."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise DependencyError(f"cannot read the version pins: {error} (the extension is incomplete; reinstall it)") from error
    pins: dict[str, str] = {}
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        match = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)\s*==\s*([^\s;]+)", line)
        if match:
            pins[canonical_name(match.group(1))] = match.group(2)
    return pins


@dataclass(frozen=True)
class Requirement:
    module: str  # import name checked with find_spec
    distribution: str  # name pip installs
    version: str  # pinned version

    @property
    def pin(self) -> str:
        return f"{self.distribution}=={self.version}"


def runtime_requirements(
    modules: Optional[dict[str, str]] = None,
    requirements_file: Path = REQUIREMENTS_FILE,
    constraints_file: Path = CONSTRAINTS_FILE,
) -> list[Requirement]:
    """The pinned runtime requirements: requirements.txt's pin, else constraints.txt's (Pillow is
    only a transitive dependency there). DependencyError names a package pinned in neither."""
    pins = {**read_pins(constraints_file), **read_pins(requirements_file)}
    out = []
    for module, distribution in (modules or RUNTIME_MODULES).items():
        version = pins.get(canonical_name(distribution))
        if version is None:
            raise DependencyError(f"{distribution} has no pinned version in {requirements_file.name} or {constraints_file.name}")
        out.append(Requirement(module, distribution, version))
    return out


# ------------------------------------------------------------------------------------------ checks


@dataclass(frozen=True)
class ModuleStatus:
    requirement: Requirement
    found_version: Optional[str]  # None: not importable; "unknown": importable, no metadata
    location: Optional[str] = None

    @property
    def missing(self) -> bool:
        return self.found_version is None

    @property
    def version_matches(self) -> bool:
        # "2.15.0+cpu" satisfies the pin "2.15.0" (PEP 440 ignores the local label for ==).
        return self.found_version is not None and self.found_version.split("+", 1)[0] == self.requirement.version

    @property
    def needs_install(self) -> bool:
        """Missing, or another version than the pinned one (the engine is tested with the pins only)."""
        return not self.version_matches and self.found_version != "unknown"

    def describe(self) -> str:
        name, pinned = self.requirement.distribution, self.requirement.version
        if self.missing:
            return f"{name}: missing (needs {pinned})"
        if self.version_matches or self.found_version == "unknown":
            return f"{name} {self.found_version}"
        return f"{name} {self.found_version} (tested with {pinned})"


def check_module(requirement: Requirement) -> ModuleStatus:
    """Whether `requirement.module` is importable and which version, without importing it (find_spec
    plus the distribution's metadata): importing torch takes seconds and the panel redraws often."""
    try:
        spec = importlib.util.find_spec(requirement.module)
    except (ImportError, ValueError):  # a broken half-installed package, or a stub in sys.modules
        spec = None
    if spec is None:
        return ModuleStatus(requirement, None)
    try:
        version = importlib.metadata.version(requirement.distribution)
    except importlib.metadata.PackageNotFoundError:
        loaded = sys.modules.get(requirement.module)
        version = str(getattr(loaded, "__version__", "unknown"))
    location = spec.origin or (list(spec.submodule_search_locations or []) or [None])[0]
    return ModuleStatus(requirement, version, location)


_status_cache: Optional[list[ModuleStatus]] = None


def status(refresh: bool = False) -> list[ModuleStatus]:
    """The runtime requirements' status, cached until `refresh` (after an install or on request)."""
    global _status_cache
    if _status_cache is None or refresh:
        importlib.invalidate_caches()
        _status_cache = [check_module(r) for r in runtime_requirements()]
    return _status_cache


def needed(statuses: Iterable[ModuleStatus]) -> list[Requirement]:
    return [s.requirement for s in statuses if s.needs_install]


# ------------------------------------------------------------------------------------------ sys.path


def add_to_sys_path(folder: Path) -> None:
    """Put `folder` on sys.path just before the first site-packages entry: ahead of packages of
    other versions that Blender's Python may have, behind Blender's own scripts/modules."""
    entry = str(folder)
    if entry in sys.path:
        return
    index = next((i for i, p in enumerate(sys.path) if p.rstrip("/\\").endswith(SITE_PACKAGES)), len(sys.path))
    sys.path.insert(index, entry)
    importlib.invalidate_caches()


def remove_from_sys_path(folder: Path) -> None:
    entry = str(folder)
    while entry in sys.path:
        sys.path.remove(entry)


def site_packages_dir(package: str) -> Path:
    """The install folder in the extension's user directory (created)."""
    import bpy

    return Path(bpy.utils.extension_path_user(package, path=SITE_PACKAGES, create=True))


# ------------------------------------------------------------------------------------------ commands


def resolve_command(python: str, pins: Sequence[str], constraints_file: Path, report_file: Path) -> list[str]:
    """pip resolves the full set for this interpreter and platform without installing anything."""
    return [
        python, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--only-binary", ":all:",
        "--report", str(report_file), "--constraint", str(constraints_file), *PIP_QUIET_FLAGS, *pins,
    ]


def install_command(python: str, target: Path, packages: Sequence[str]) -> list[str]:
    """pip installs exactly `packages` (the resolved set, numpy removed) into `target`.

    --upgrade replaces older copies already in the folder (pip --target otherwise skips them);
    --only-binary: Blender's Python has no headers to build from source, so fail clearly instead.
    """
    return [
        python, "-m", "pip", "install", "--target", str(target), "--no-deps", "--upgrade", "--only-binary", ":all:",
        *PIP_QUIET_FLAGS, *packages,
    ]


def packages_from_report(report: dict) -> list[str]:
    """`name==version` of every distribution in a pip installation report, minus BLENDER_PROVIDED."""
    packages = []
    for item in report.get("install", []):
        metadata = item["metadata"]
        if canonical_name(metadata["name"]) not in BLENDER_PROVIDED:
            packages.append(f"{metadata['name']}=={metadata['version']}")
    return packages


def constraints_text(pins: dict[str, str], numpy_version: Optional[str]) -> str:
    """The constraints for resolving: the tested pins, with numpy held at Blender's own version so
    nothing that needs another numpy is chosen."""
    lines = [f"{name}=={version}" for name, version in sorted(pins.items()) if name not in BLENDER_PROVIDED]
    if numpy_version:
        lines.append(f"numpy=={numpy_version}")
    return "\n".join(lines) + "\n"


def blender_numpy_version() -> Optional[str]:
    try:
        return importlib.metadata.version("numpy")
    except importlib.metadata.PackageNotFoundError:
        return None


def manual_command(python: str, target: Path) -> list[str]:
    """The command that does what the Install button does, for users who keep online access off."""
    return [python, str(Path(__file__).resolve()), "--target", str(target)]


def quote_command(argv: Sequence[str]) -> str:
    """argv as one line to copy into a shell (double quotes work in sh, PowerShell and cmd)."""
    return " ".join(f'"{a}"' if (not a or re.search(r"[\s\"'&|<>^]", a)) else a for a in argv)


def offline_message(requirements: Sequence[Requirement], command: Sequence[str]) -> str:
    names = ", ".join(r.pin for r in requirements)
    return (
        "Online access is disabled in Preferences > System > Network; enable it or install "
        f"{names} manually with: {quote_command(command)}"
    )


# ------------------------------------------------------------------------------------------ running pip


def run_pip(
    argv: Sequence[str],
    stage: str,
    progress: Optional[ProgressFn] = None,
    cancel: Optional[CancelFlag] = None,
    total: int = 0,
    poll_interval: float = 0.1,
) -> list[str]:
    """Run one pip command, reporting each "Collecting"/"Downloading"/"Installing" line as progress.

    Cancel kills pip (pip --target stages into a temporary folder and moves it in at the end, so a
    killed install leaves the target as it was) and raises Cancelled. Returns pip's output lines;
    DependencyError with pip's last error lines when it fails.
    """
    env = dict(os.environ, PYTHONNOUSERSITE="1", PIP_NO_INPUT="1")
    try:
        process = subprocess.Popen(
            list(argv), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, encoding="utf-8",
            errors="replace", env=env, bufsize=1,
        )
    except OSError as error:
        raise DependencyError(f"cannot run {argv[0]}: {error}") from error
    lines: "queue.Queue[Optional[str]]" = queue.Queue()

    def read() -> None:  # a thread, so the loop below can check cancel while pip is silent for minutes
        assert process.stdout is not None
        for line in process.stdout:
            lines.put(line.rstrip())
        lines.put(None)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    output: list[str] = []
    done = 0
    finished = False
    while not finished:
        if cancel is not None and cancel.cancelled:
            process.terminate()
            try:
                process.wait(5)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            raise Cancelled()
        try:
            line = lines.get(timeout=poll_interval)
        except queue.Empty:
            continue
        if line is None:
            finished = True
            continue
        output.append(line)
        if line.startswith(("Collecting ", "Downloading ", "Installing ", "Would install ")):
            if line.startswith("Collecting "):
                done += 1
            if progress is not None:
                progress(f"{stage}: {line[:120]}", done, max(total, done))
    code = process.wait()
    if code != 0:
        errors = [l for l in output if l.startswith("ERROR")] or output[-5:]
        if any("No module named pip" in l for l in output):
            errors = [f"pip is not available in this Python; run: {quote_command([argv[0], '-m', 'ensurepip'])}"]
        raise DependencyError(f"pip failed (exit code {code}): " + " ".join(errors)[-600:])
    return output


@dataclass(frozen=True)
class InstallResult:
    target: Path
    packages: list[str]  # name==version installed


def install(
    python: str,
    target: Path,
    requirements: Sequence[Requirement],
    progress: Optional[ProgressFn] = None,
    cancel: Optional[CancelFlag] = None,
    constraints_file: Path = CONSTRAINTS_FILE,
    requirements_file: Path = REQUIREMENTS_FILE,
) -> InstallResult:
    """Resolve, then install `requirements` and their dependencies (never numpy) into `target`."""
    if not requirements:
        raise DependencyError("all required packages are already installed")
    target = Path(target)
    target.mkdir(parents=True, exist_ok=True)
    pins = {**read_pins(constraints_file), **read_pins(requirements_file)}
    with tempfile.TemporaryDirectory(prefix="vortx-pip-") as tmp:
        constraints = Path(tmp) / "constraints.txt"
        constraints.write_text(constraints_text(pins, blender_numpy_version()), encoding="utf-8")
        report_file = Path(tmp) / "report.json"
        wanted = [r.pin for r in requirements]
        run_pip(resolve_command(python, wanted, constraints, report_file), "resolving", progress, cancel)
        packages = packages_from_report(json.loads(report_file.read_text(encoding="utf-8")))
        if not packages:
            raise DependencyError("pip resolved nothing to install for " + ", ".join(wanted))
        run_pip(install_command(python, target, packages), "installing", progress, cancel, total=len(packages))
    return InstallResult(target, packages)


def install_job(python: str, target: Path, requirements: Sequence[Requirement]) -> Callable[[ProgressFn, CancelFlag], InstallResult]:
    """`install` as a job function for vortx_blender.jobs.Job (runs in its worker thread)."""

    def run(progress: ProgressFn, cancel: CancelFlag) -> InstallResult:
        return install(python, target, requirements, progress, cancel)

    return run


# ------------------------------------------------------------------------------------------ script


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description="Install the VoRTX engine's Python packages (never numpy) into a folder.")
    parser.add_argument("--target", type=Path, required=True, help="the extension's site-packages folder (shown in its preferences)")
    args = parser.parse_args(argv)
    add_to_sys_path(args.target)  # what is already there counts as installed, as inside Blender
    todo = needed(status(refresh=True))
    if not todo:
        print("all required packages are already installed")
        return 0
    last = [""]

    def show(stage: str, done: int, total: int) -> None:
        if stage != last[0]:
            last[0] = stage
            print(stage, flush=True)

    try:
        result = install(sys.executable, args.target, todo, progress=show)
    except VortxError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    print(f"installed {len(result.packages)} packages into {result.target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
