"""The engine's Python packages inside Blender: detection, the pip commands, the install job (with a
fake pip, never the network), the offline message, the install folder on sys.path, the preferences."""

from __future__ import annotations

import json
import os
import stat
import sys
import textwrap
import time
from pathlib import Path

import pytest

from conftest import EXTENSION_MODULE, REPO


@pytest.fixture
def deps(blender):
    return blender.vortx_blender.dependencies


# --- detection -----------------------------------------------------------------------------------


def test_missing_module_is_detected_by_name(deps) -> None:
    missing = deps.check_module(deps.Requirement("vortx_no_such_module_xyz", "vortx-no-such-dist", "1.0"))
    assert missing.missing and missing.needs_install and missing.found_version is None
    assert missing.describe() == "vortx-no-such-dist: missing (needs 1.0)"

    import numpy

    present = deps.check_module(deps.Requirement("numpy", "numpy", numpy.__version__))
    assert not present.needs_install and present.found_version == numpy.__version__
    assert present.location and Path(present.location).parent.name == "numpy"
    other = deps.check_module(deps.Requirement("numpy", "numpy", "0.0.1"))
    assert other.needs_install and other.describe() == f"numpy {numpy.__version__} (tested with 0.0.1)"


def test_local_version_label_satisfies_the_pin(deps) -> None:
    requirement = deps.Requirement("torch", "torch", "2.15.0")
    assert deps.ModuleStatus(requirement, "2.15.0+cpu").version_matches
    assert not deps.ModuleStatus(requirement, "2.15.1").version_matches


def test_runtime_pins_come_from_requirements_then_constraints(deps) -> None:
    requirements = {r.distribution: r.version for r in deps.runtime_requirements()}
    direct = deps.read_pins(REPO / "requirements.txt")
    transitive = deps.read_pins(REPO / "constraints.txt")
    assert requirements["torch"] == direct["torch"] and requirements["pycolmap"] == direct["pycolmap"]
    assert "pillow" not in direct and requirements["pillow"] == transitive["pillow"]
    assert "numpy" not in requirements  # Blender ships numpy
    # In the test venv everything the engine needs is present, at the pinned versions.
    assert deps.needed(deps.status(refresh=True)) == []


def test_unpinned_runtime_package_is_an_error(deps, tmp_path: Path) -> None:
    (tmp_path / "req.txt").write_text("torch==2.15.0  # comment\n")
    (tmp_path / "con.txt").write_text("Pillow==13.0.0\n")
    pins = deps.runtime_requirements({"torch": "torch", "PIL": "pillow"}, tmp_path / "req.txt", tmp_path / "con.txt")
    assert [r.pin for r in pins] == ["torch==2.15.0", "pillow==13.0.0"]
    with pytest.raises(deps.DependencyError, match="cv-nothing has no pinned version"):
        deps.runtime_requirements({"cv2": "cv-nothing"}, tmp_path / "req.txt", tmp_path / "con.txt")
    with pytest.raises(deps.DependencyError, match="reinstall"):
        deps.read_pins(tmp_path / "absent.txt")


# --- the commands ----------------------------------------------------------------------------------


def test_pip_commands(deps, tmp_path: Path) -> None:
    target = tmp_path / "site packages"
    resolve = deps.resolve_command("/py", ["torch==2.15.0", "pycolmap==4.2.1"], tmp_path / "c.txt", tmp_path / "r.json")
    assert resolve[:4] == ["/py", "-m", "pip", "install"]
    assert {"--dry-run", "--ignore-installed"} <= set(resolve) and "--target" not in resolve
    assert resolve[resolve.index("--report") + 1] == str(tmp_path / "r.json")
    assert resolve[resolve.index("--constraint") + 1] == str(tmp_path / "c.txt")
    assert resolve[-2:] == ["torch==2.15.0", "pycolmap==4.2.1"]

    report = {"install": [{"metadata": {"name": "torch", "version": "2.15.0"}},
                          {"metadata": {"name": "NumPy", "version": "1.26.4"}},
                          {"metadata": {"name": "sympy", "version": "1.14.0"}}]}
    packages = deps.packages_from_report(report)
    assert packages == ["torch==2.15.0", "sympy==1.14.0"]  # numpy never, whatever its spelling
    install = deps.install_command("/py", target, packages)
    assert install[:4] == ["/py", "-m", "pip", "install"]
    assert install[install.index("--target") + 1] == str(target)
    assert {"--no-deps", "--upgrade"} <= set(install) and "--dry-run" not in install
    assert install[-2:] == packages and not any("numpy" in a.lower() for a in install)


def test_resolution_holds_numpy_at_blenders_version(deps) -> None:
    text = deps.constraints_text({"torch": "2.15.0", "numpy": "1.26.4", "scipy": "1.17.1"}, "1.25.0")
    assert text.splitlines() == ["scipy==1.17.1", "torch==2.15.0", "numpy==1.25.0"]


def test_offline_message_names_packages_and_command(deps, tmp_path: Path) -> None:
    todo = [deps.Requirement("torch", "torch", "2.15.0"), deps.Requirement("cv2", "opencv-python-headless", "4.11.0.86")]
    target = tmp_path / "my user" / "site-packages"
    message = deps.offline_message(todo, deps.manual_command("/opt/blender/python3.11", target))
    script = Path(deps.__file__).resolve()
    assert message == (
        "Online access is disabled in Preferences > System > Network; enable it or install "
        "torch==2.15.0, opencv-python-headless==4.11.0.86 manually with: "
        f'/opt/blender/python3.11 {script} --target "{target}"'
    )


def test_install_operator_is_gated_on_online_access(blender) -> None:
    import bpy

    if bpy.app.online_access:
        pytest.skip("this Blender runs with online access on; the gate is only visible offline")
    assert not bpy.ops.vortx.install_dependencies.poll()


# --- the install folder on sys.path ---------------------------------------------------------------


def test_install_folder_is_on_sys_path_and_importable(blender, deps) -> None:
    import addon_utils

    folder = blender.vortx_blender.preferences.install_folder()
    user = Path(os.environ["BLENDER_USER_RESOURCES"]).resolve()
    assert folder.resolve() == user / "extensions" / ".user" / "dev" / "vortx" / "site-packages"
    assert str(folder) in sys.path
    venv_site = next(i for i, p in enumerate(sys.path) if p.endswith("site-packages") and p != str(folder))
    assert sys.path.index(str(folder)) < venv_site  # ahead of other copies of the same packages

    # A package installed there is found, with its version from its metadata.
    (folder / "vortx_probe_pkg").mkdir(exist_ok=True)
    (folder / "vortx_probe_pkg" / "__init__.py").write_text("")
    (folder / "vortx_probe_pkg-1.2.3.dist-info").mkdir(exist_ok=True)
    (folder / "vortx_probe_pkg-1.2.3.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: vortx-probe-pkg\nVersion: 1.2.3\n")
    probe = deps.Requirement("vortx_probe_pkg", "vortx-probe-pkg", "1.2.3")
    try:
        import importlib

        importlib.invalidate_caches()
        found = deps.check_module(probe)
        assert found.found_version == "1.2.3" and not found.needs_install, found
        addon_utils.disable(EXTENSION_MODULE, default_set=True)
        assert str(folder) not in sys.path
        importlib.invalidate_caches()
        assert deps.check_module(probe).missing
    finally:
        addon_utils.enable(EXTENSION_MODULE, default_set=True)
    assert str(folder) in sys.path


# --- the install job, with a fake pip --------------------------------------------------------------

FAKE_PYTHON = textwrap.dedent(
    """\
    #!{python}
    # Stands in for `python -m pip install ...`: logs argv, writes the dry-run report, "installs" by
    # creating one package folder per name==version; FAKE_PIP_SLEEP makes the install hang (cancel test).
    import json, os, sys, time
    from pathlib import Path
    args = sys.argv[1:]
    assert args[:3] == ["-m", "pip", "install"], args
    with open(os.environ["FAKE_PIP_LOG"], "a") as log:
        log.write(json.dumps(args) + "\\n")
    specs = [a for a in args if "==" in a]
    for spec in specs:
        print("Collecting " + spec, flush=True)
    if "--dry-run" in args:
        report = {{"install": [{{"metadata": {{"name": n, "version": v}}}} for n, v in (s.split("==") for s in specs)]}}
        report["install"].append({{"metadata": {{"name": "numpy", "version": "1.26.4"}}}})
        report["install"].append({{"metadata": {{"name": "sympy", "version": "1.14.0"}}}})
        Path(args[args.index("--report") + 1]).write_text(json.dumps(report))
        sys.exit(0)
    if os.environ.get("FAKE_PIP_SLEEP"):
        time.sleep(float(os.environ["FAKE_PIP_SLEEP"]))
    if os.environ.get("FAKE_PIP_FAIL"):
        print("ERROR: No matching distribution found for torch==2.15.0", flush=True)
        sys.exit(1)
    target = Path(args[args.index("--target") + 1])
    for spec in specs:
        (target / spec.split("==")[0]).mkdir(parents=True, exist_ok=True)
    print("Successfully installed " + " ".join(specs), flush=True)
    """
)


@pytest.fixture
def fake_python(tmp_path: Path, monkeypatch) -> Path:
    path = tmp_path / "fake-python"
    path.write_text(FAKE_PYTHON.format(python=sys.executable))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("FAKE_PIP_LOG", str(tmp_path / "pip-calls.jsonl"))
    return path


def _calls(tmp_path: Path) -> list[list[str]]:
    return [json.loads(line) for line in (tmp_path / "pip-calls.jsonl").read_text().splitlines()]


def test_install_job_resolves_then_installs_without_numpy(blender, deps, fake_python: Path, tmp_path: Path) -> None:
    jobs = blender.vortx_blender.jobs
    target = tmp_path / "target"
    todo = [deps.Requirement("torch", "torch", "2.15.0"), deps.Requirement("skimage", "scikit-image", "0.24.0")]
    stages: list[str] = []
    result = jobs.Job("Install Packages", deps.install_job(str(fake_python), target, todo)).start().wait(
        on_progress=lambda p: stages.append(p.stage)
    )
    resolve, install = _calls(tmp_path)
    assert "--dry-run" in resolve and resolve[-2:] == ["torch==2.15.0", "scikit-image==0.24.0"]
    constraints = Path(resolve[resolve.index("--constraint") + 1])
    assert not constraints.exists()  # a temporary file, gone after the run
    assert install[install.index("--target") + 1] == str(target) and "--no-deps" in install
    assert install[-3:] == ["torch==2.15.0", "scikit-image==0.24.0", "sympy==1.14.0"]
    assert result.packages == install[-3:] and result.target == target
    assert sorted(p.name for p in target.iterdir()) == ["scikit-image", "sympy", "torch"]
    assert any(s.startswith("resolving: Collecting torch") for s in stages)
    assert any(s.startswith("installing: Collecting sympy") for s in stages)


def test_install_job_cancel_kills_pip(blender, deps, fake_python: Path, tmp_path: Path, monkeypatch) -> None:
    jobs = blender.vortx_blender.jobs
    monkeypatch.setenv("FAKE_PIP_SLEEP", "60")
    target = tmp_path / "target"
    job = jobs.Job("Install Packages", deps.install_job(str(fake_python), target, [deps.Requirement("torch", "torch", "2.15.0")]))
    job.start()
    deadline = time.monotonic() + 20
    while len(_calls(tmp_path) if (tmp_path / "pip-calls.jsonl").exists() else []) < 2:  # the install step is running
        assert time.monotonic() < deadline
        time.sleep(0.05)
    started = time.monotonic()
    job.cancel()
    with pytest.raises(blender.engine.errors.Cancelled):
        job.wait()
    assert time.monotonic() - started < 10  # pip was killed, not waited for
    assert list(target.iterdir()) == []


def test_install_job_failure_names_pips_error(blender, deps, fake_python: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("FAKE_PIP_FAIL", "1")
    with pytest.raises(deps.DependencyError, match="exit code 1.*No matching distribution found for torch==2.15.0"):
        deps.install(str(fake_python), tmp_path / "t", [deps.Requirement("torch", "torch", "2.15.0")])


# --- the preferences panel -------------------------------------------------------------------------


def test_preferences_draw_missing_packages(blender, deps, tmp_path: Path) -> None:
    from fixtures_blender_ui import RecordingLayout

    preferences = blender.vortx_blender.preferences
    assert preferences.ADDON_PACKAGE == EXTENSION_MODULE
    present = deps.ModuleStatus(deps.Requirement("torch", "torch", "2.15.0"), "2.15.0")
    absent = deps.ModuleStatus(deps.Requirement("pycolmap", "pycolmap", "4.2.1"), None)

    def labels(online: bool) -> tuple[list[str], list[str]]:
        calls: list = []
        preferences.draw_dependencies(RecordingLayout(calls), [present, absent], online, None, tmp_path)
        return ([c[1].get("text", "") for c in calls if c[0] == "label"], [c[1]["operator"] for c in calls if c[0] == "operator"])

    texts, operators = labels(online=True)
    assert "torch 2.15.0" in texts and "pycolmap: missing (needs 4.2.1)" in texts
    assert "vortx.install_dependencies" in operators
    texts, operators = labels(online=False)
    offline = " ".join(texts)
    assert "Online access is disabled in Preferences > System > Network; enable it or install pycolmap==4.2.1 manually" in offline
    assert f"--target {tmp_path}" in offline and "vortx.install_dependencies" not in operators and "vortx.copy_install_command" in operators

    calls: list = []
    preferences.draw_dependencies(RecordingLayout(calls), [present], False, None, tmp_path)
    assert ("label", {"text": "All packages found", "icon": "INFO"}) in calls
