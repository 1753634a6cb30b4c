"""Run the whole Blender workflow in a real, windowed Blender and collect its screenshots.

    sudo .venv/bin/python scripts/gui_workflow.py [--root ROOT] [--photos DIR | --phone-export DIR] [--shots docs/]

The Blender is a Linux distribution's, in a chroot built by ../shared/tools/gui_blender_setup.sh
(Debian 13: Blender 4.3 on Python 3.13 with numpy 2.2, Xvfb, ImageMagick; ROOT defaults to
$TRIXIE_ROOT or ~/trixie-root). As a user would:
1. `make extension`'s zip (scripts/build_extension.py) is installed with Blender's own
   `blender --command extension install-file -r user_default -e <zip>`;
2. the engine's packages are installed, if missing, by the add-on's own Install Missing Packages
   (vortx_blender/dependencies.py, which picks versions that fit that Python and its numpy);
3. scripts/gui_workflow_blender.py (with devtools/gui_workflow/, copied into the root beside it)
   drives the workflow in the window under Xvfb and writes report.json and the screenshots; with
   --shots they are copied there (the README's pictures). With --phone-export (a phone app's export
   folder or zip, e.g. the 3D Scanner App's All Data) it is that capture's variant instead
   (devtools/gui_workflow/phone.py): Import Capture, Reconstruct with every default, the
   docs/gui_phone_* screenshots.

tests/extension/test_gui_workflow.py runs this when such a root is present. The chroot gets a clean
environment (env -i): the host's proxy certificate settings are the root's own /etc/pip.conf.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Optional, Sequence

CHECKOUT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(CHECKOUT / "scripts"))
from build_extension import build  # noqa: E402  (scripts/ is not a package)

DEFAULT_PHOTOS = CHECKOUT / "samples" / "demo_room" / "images"
DRIVER = CHECKOUT / "scripts" / "gui_workflow_blender.py"
SCREEN = "1600x1000x24"  # issue 29: the Capture panel fits above the Reconstruction panel on such a screen
# Inside the chroot: a clean environment, the software GL that Xvfb needs.
CHROOT_ENV = ["env", "-i", "HOME=/root", "PATH=/usr/local/bin:/usr/bin:/bin", "LANG=C.UTF-8", "LIBGL_ALWAYS_SOFTWARE=1"]
INSTALL_PACKAGES = """\
import bpy
bpy.context.preferences.view.show_splash = False  # the splash screen would cover the viewport in the screenshots
bpy.ops.wm.save_userpref()
from bl_ext.user_default.vortx.vortx_blender import dependencies
if any(s.needs_install for s in dependencies.status(refresh=True)):
    print("GUI-WORKFLOW install:", bpy.ops.vortx.install_dependencies())  # the preferences' button
for status in dependencies.status(refresh=True):
    print("GUI-WORKFLOW package:", status.describe(), "(missing)" if status.needs_install else "")
"""


class GuiUnavailable(Exception):
    """No windowed Blender root here; the message says what is missing."""


def default_root() -> Path:
    return Path(os.environ.get("TRIXIE_ROOT") or Path.home() / "trixie-root")


def copy_driver(folder: Path) -> Path:
    """The driver script and the code it runs (devtools/gui_workflow/) into `folder`, laid out as in the
    checkout (the driver puts its folder's parent on sys.path); returns the driver's path in `folder`."""
    driver = DRIVER.relative_to(CHECKOUT)
    (folder / driver).parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(DRIVER, folder / driver)
    shutil.copytree(CHECKOUT / "devtools" / "gui_workflow", folder / "devtools" / "gui_workflow",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(CHECKOUT / "devtools" / "__init__.py", folder / "devtools" / "__init__.py")
    return driver


def check_root(root: Path) -> None:
    """GuiUnavailable naming what is missing for a GUI run in `root`."""
    needed = ("usr/bin/blender", "usr/bin/xvfb-run", "usr/bin/import", "usr/bin/xdotool")
    # lexists: the root's own links are absolute (/etc/alternatives/...), meaningful inside it only.
    absent = [p for p in needed if not os.path.lexists(root / p)]
    if absent:
        raise GuiUnavailable(f"no windowed Blender root at {root} (missing {', '.join(absent)}): "
                             "build one with ../shared/tools/gui_blender_setup.sh (as root), then "
                             f"`chroot {root} apt-get install -y xdotool` (it switches the sidebar's tab)")
    if os.geteuid() != 0:
        raise GuiUnavailable(f"{root} needs chroot, which needs root")
    if not (root / "proc" / "self").exists():
        raise GuiUnavailable(f"{root}/proc is not mounted: run ../shared/tools/gui_blender_setup.sh again (it mounts it)")


def chroot(root: Path, command: Sequence[str], timeout: float, log: Path) -> subprocess.CompletedProcess:
    run = subprocess.run(["chroot", str(root), *CHROOT_ENV, *command], capture_output=True, text=True, timeout=timeout)
    with log.open("a", encoding="utf-8") as out:
        out.write(f"$ {' '.join(command)}\n{run.stdout}{run.stderr}\n")
    return run


def run_workflow(root: Path, photos: Path = DEFAULT_PHOTOS, shots: Optional[Path] = None, timeout: float = 3600,
                 phone_export: Optional[Path] = None, quality: Optional[str] = None) -> dict:
    """Build, install, drive; returns report.json's content plus `log` (the chroot commands' output).
    With `phone_export` (a folder or zip) the phone-capture variant runs instead of the photos' workflow,
    at the panel's default Quality unless `quality` (PREVIEW, STANDARD, ...) says otherwise."""
    check_root(root)
    work_in_root = Path(tempfile.mkdtemp(prefix="vortx-gui-", dir=root / "tmp"))
    inside = Path("/") / work_in_root.relative_to(root)  # the same folder as the chroot sees it
    log = work_in_root / "log.txt"
    try:
        archive = build(CHECKOUT, work_in_root / "dist")
        if phone_export is None:
            shutil.copytree(photos, work_in_root / "photos")
            capture = ["--photos", str(inside / "photos")]
        else:  # the export's own name: Import Capture detects the format from its contents
            copied = work_in_root / "photos" / phone_export.name
            (shutil.copytree if phone_export.is_dir() else shutil.copy)(phone_export, copied)
            capture = ["--phone-export", str(inside / copied.relative_to(work_in_root))] + (["--quality", quality] if quality else [])
        driver = copy_driver(work_in_root)
        (work_in_root / "install_packages.py").write_text(INSTALL_PACKAGES)
        zip_inside = inside / "dist" / archive.name
        installed = chroot(root, ["blender", "--command", "extension", "install-file", "-r", "user_default", "-e", str(zip_inside)], 300, log)
        if installed.returncode != 0 or "nstalled \"vortx\"" not in installed.stdout:  # Installed or Reinstalled
            raise RuntimeError(f"installing {archive.name} failed:\n{installed.stdout[-2000:]}{installed.stderr[-2000:]}")
        packages = chroot(root, ["blender", "--background", "--online-mode", "--python", str(inside / "install_packages.py")], 3600, log)
        if "(missing)" in packages.stdout or packages.returncode != 0:
            raise RuntimeError(f"the engine's packages are not all installed:\n{packages.stdout[-3000:]}{packages.stderr[-2000:]}")
        gui = chroot(root, [
            "xvfb-run", "-a", "-s", f"-screen 0 {SCREEN}",
            "blender", "--window-geometry", "0", "0", *SCREEN.split("x")[:2], "--no-window-focus",
            "--python", str(inside / driver), "--", *capture, "--out", str(inside / "out"),
        ], timeout, log)
        report_file = work_in_root / "out" / "report.json"
        if not report_file.is_file():
            raise RuntimeError(f"Blender wrote no report (exit code {gui.returncode}):\n{gui.stdout[-3000:]}{gui.stderr[-2000:]}")
        report = json.loads(report_file.read_text())
        report["log"] = log.read_text()
        report["out"] = str(work_in_root / "out")
        if shots is not None:
            shots.mkdir(parents=True, exist_ok=True)
            for shot in report["shots"]:
                shutil.copy(work_in_root / "out" / shot["file"], shots / shot["file"])
        return report
    finally:
        if shots is not None or os.environ.get("VORTX_GUI_KEEP") != "1":
            shutil.rmtree(work_in_root / "photos", ignore_errors=True)


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=default_root(), help="the chroot (default: $TRIXIE_ROOT or ~/trixie-root)")
    parser.add_argument("--photos", type=Path, default=DEFAULT_PHOTOS, help="a folder of photos (default: the demo room)")
    parser.add_argument("--phone-export", type=Path, help="a phone app's export folder or zip (e.g. the 3D Scanner App's "
                        "All Data): Import Capture and Reconstruct with every default on it instead")
    parser.add_argument("--quality", type=str.upper, help="with --phone-export: the Quality chosen before Reconstruct "
                        "(PREVIEW, STANDARD, ...; default: the panel's default)")
    parser.add_argument("--shots", type=Path, help="copy the screenshots here (e.g. docs/)")
    args = parser.parse_args(argv)
    try:
        report = run_workflow(args.root, args.photos.resolve(), args.shots,
                              phone_export=args.phone_export.resolve() if args.phone_export else None, quality=args.quality)
    except GuiUnavailable as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    for step in report["steps"]:
        print(f"{step['step']}: {step.get('seconds', '-')} s, " + ", ".join(("ok " if c["ok"] else "FAILED ") + c["check"] for c in step["checks"]))
    for shot in report["shots"]:
        print(f"screenshot {shot['file']} ({shot['bytes'] // 1024} KB): {shot['what']}")
    print("OK" if report["ok"] else f"FAILED: {report.get('error')}")
    print(f"output: {report['out']}")
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
