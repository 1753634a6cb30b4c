"""Load this checkout into a running bpy as the `vortx` extension, exactly as an installed copy runs.

Shared by the test fixture (tests/conftest.py), the batch script (scripts/vortx_batch.py) and the demo
(scripts/demo.py), so they cannot drift apart. A local extension repository is a folder holding one folder per extension
id; a symlink named `vortx` to the checkout makes Blender import it as `bl_ext.<repo>.vortx`, so
`__package__`, relative imports and `bpy.utils.extension_path_user` behave as after an install
(blender-notes.md section 7).

Only `bpy` and `addon_utils` are needed; both are imported lazily so that importing this module
does not start Blender.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Iterator, Optional

EXTENSION_ID = "vortx"
CHECKOUT = Path(__file__).resolve().parent.parent
BATCH_REPO = "vortx_checkout"  # repository name when a script mounts this checkout: bl_ext.vortx_checkout.vortx


class ExtensionLoadError(RuntimeError):
    """The extension could not be found or enabled; the message says why."""


def extension_module(repo_module: str) -> str:
    return f"bl_ext.{repo_module}.{EXTENSION_ID}"


def find_extension() -> Optional[str]:
    """The module name of a `vortx` extension this Blender already has (enabled first, then merely
    installed in an enabled repository), or None."""
    import bpy

    preferences = bpy.context.preferences
    for name in preferences.addons.keys():
        if name.startswith("bl_ext.") and name.rsplit(".", 1)[-1] == EXTENSION_ID:
            return name
    for repo in preferences.extensions.repos:
        if repo.enabled and repo.directory and (Path(repo.directory) / EXTENSION_ID / "blender_manifest.toml").is_file():
            return extension_module(repo.module)
    return None


def enable(module_name: str) -> object:
    """Enable an extension module and return it; ExtensionLoadError with the cause when it fails
    (addon_utils only prints the traceback and returns None)."""
    import addon_utils

    errors: list[BaseException] = []
    addon_utils.enable(module_name, default_set=True, handle_error=errors.append)
    module = sys.modules.get(module_name)
    if errors or module is None:
        cause = f": {errors[0]!r}" if errors else ""
        raise ExtensionLoadError(f"could not enable the extension {module_name}{cause}")
    return module


def mount_checkout(repo_dir: Path, repo_module: str = "dev", checkout: Path = CHECKOUT) -> str:
    """Register `checkout` as extension `vortx` in a local repository folder `repo_dir` (created,
    with a `vortx` symlink to the checkout) named `repo_module`, enable it, return its module name."""
    import bpy

    repo_dir = Path(repo_dir)
    repo_dir.mkdir(parents=True, exist_ok=True)
    link = repo_dir / EXTENSION_ID
    if link.is_symlink() and link.resolve() != checkout.resolve():
        link.unlink()  # left over from another checkout
    if not link.exists():
        link.symlink_to(checkout, target_is_directory=True)
    repos = bpy.context.preferences.extensions.repos
    existing = next((r for r in repos if r.module == repo_module), None)
    if existing is None:
        repos.new(name=repo_module, module=repo_module, custom_directory=str(repo_dir), source="USER")
    elif Path(existing.directory).resolve() != repo_dir.resolve():
        raise ExtensionLoadError(
            f"an extension repository '{repo_module}' already exists at {existing.directory}; "
            f"cannot mount {checkout} there"
        )
    module_name = extension_module(repo_module)
    enable(module_name)
    return module_name


def unmount(repo_module: str) -> None:
    """Remove the mounted repository from the (in-memory) preferences, so nothing of a batch run is
    left behind should the preferences be saved later. Blender disables the repository's add-ons
    itself when it is removed (disabling first makes it print a spurious "not enabled")."""
    import bpy

    repos = bpy.context.preferences.extensions.repos
    for repo in list(repos):
        if repo.module == repo_module:
            repos.remove(repo)


@contextmanager
def vortx_extension() -> Iterator[ModuleType]:
    """The enabled `vortx` add-on module: an installed one, else this checkout mounted for this run
    (and unmounted after, so nothing of it stays in the preferences)."""
    installed = find_extension()
    if installed is not None:
        yield enable(installed)
        return
    repo_dir = Path(tempfile.mkdtemp(prefix="vortx-batch-repo-"))
    try:
        module_name = mount_checkout(repo_dir, repo_module=BATCH_REPO)
        yield sys.modules[module_name]
    finally:
        try:
            unmount(BATCH_REPO)
        finally:
            shutil.rmtree(repo_dir, ignore_errors=True)
