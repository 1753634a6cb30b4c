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
    specs = args[args.index("off") + 1:]  # after PIP_QUIET_FLAGS: what is asked for, pinned or not
    for spec in specs:
        print("Collecting " + spec, flush=True)
    # FAKE_PIP_NO_WHEEL: specs this "index" has no wheel for, answered in pip's own words.
    refused = [s for s in specs if s in os.environ.get("FAKE_PIP_NO_WHEEL", "").split(",")]
    if "--dry-run" in args and refused:
        print("ERROR: Could not find a version that satisfies the requirement " + refused[0] + " (from versions: none)")
        print("ERROR: No matching distribution found for " + refused[0], flush=True)
        sys.exit(1)
    if "--dry-run" in args:
        versions = [s.split("==") if "==" in s else [s, "9.9.9"] for s in specs]
        report = {{"install": [{{"metadata": {{"name": n, "version": v}}}} for n, v in versions]}}
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
    assert all("==" in s for s in specs), specs  # the install step gets the resolved versions
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


# --- the version choice on a Python other than the tested one (Debian's Blender: 3.13, numpy 2.2) -----

# pip 25's own output, as it prints it (captured from real runs against PyPI).
PIP_NO_WHEEL = [
    "Collecting scikit-image==0.24.0",
    "ERROR: Could not find a version that satisfies the requirement scikit-image==0.24.0 (from versions: 0.25.0, 0.25.2, 0.26.0)",
    "ERROR: No matching distribution found for scikit-image==0.24.0",
]
PIP_CONFLICT = [
    "ERROR: Cannot install scikit-image because these package versions have conflicting dependencies.",
    "",
    "The conflict is caused by:",
    "    scikit-image 0.26.0 depends on numpy>=2.3",
    "    The user requested (constraint) numpy==2.2.4",
    "",
    "To fix this you could try to:",
    "ERROR: ResolutionImpossible: for help visit https://pip.pypa.io/en/latest/topics/dependency-resolution/",
]
PIP_OFFLINE = [
    "WARNING: Retrying (Retry(total=4)) after connection broken by 'NewConnectionError': /simple/torch/",
    "ERROR: Could not find a version that satisfies the requirement torch==2.15.0 (from versions: none)",
    "ERROR: No matching distribution found for torch==2.15.0",
]


def _requirements(deps):
    return [deps.Requirement("torch", "torch", "2.15.0"), deps.Requirement("skimage", "scikit-image", "0.24.0")]


def test_tested_python_is_the_one_the_suite_runs(deps) -> None:
    # The pins are the .venv's freeze; the suite runs in that .venv.
    assert deps.TESTED_PYTHON == tuple(sys.version_info[:2]) and deps.pins_apply_here()


def test_first_attempt_keeps_the_tested_set_only_on_the_tested_python(deps) -> None:
    pins = {"torch": "2.15.0", "scikit-image": "0.24.0", "numpy": "1.26.4", "tifffile": "2026.3.3"}
    tested = deps.first_attempt(_requirements(deps), pins, deps.TESTED_PYTHON, "1.26.4")
    assert tested.specs() == ["torch==2.15.0", "scikit-image==0.24.0"]
    assert tested.constraints_text().splitlines() == ["tifffile==2026.3.3", "numpy==1.26.4"]
    debian = deps.first_attempt(_requirements(deps), pins, (3, 13), "2.2.4")
    assert debian.specs() == ["torch==2.15.0", "scikit-image==0.24.0"]  # the direct pins are still tried first
    assert debian.constraints_text().splitlines() == ["numpy==2.2.4"]  # the 3.11 freeze is not; numpy held


def test_pip_failures_are_read_as_resolution_or_not(deps) -> None:
    missing = deps.parse_resolution_failure(PIP_NO_WHEEL)
    assert missing.blamed == ("scikit-image",) and missing.no_wheel
    conflict = deps.parse_resolution_failure(PIP_CONFLICT)
    assert set(conflict.blamed) == {"scikit-image", "numpy"} and not conflict.no_wheel
    assert "depends on numpy>=2.3" in conflict.pip_says
    assert deps.parse_resolution_failure(["ERROR: Could not install packages due to an OSError: [Errno 28] No space left"]) is None
    assert deps.parse_resolution_failure(PIP_OFFLINE) is None  # offline: no version is to blame


def test_a_pin_without_a_wheel_is_loosened_then_an_unfit_package_left_out_in_plain_words(deps) -> None:
    attempt = deps.first_attempt(_requirements(deps), {}, (3, 13), "2.2.4")
    loosened, dropped, why = deps.relax(attempt, deps.parse_resolution_failure(PIP_NO_WHEEL), (3, 13))
    assert loosened.specs() == ["torch==2.15.0", "scikit-image"] and dropped == []
    assert why == {"scikit-image": "0.24.0 has no wheel for Python 3.13"}
    # Even the newest scikit-image needs another numpy than Blender's: it is left out, torch stays.
    left, dropped, why = deps.relax(loosened, deps.parse_resolution_failure(PIP_CONFLICT), (3, 13))
    assert left.specs() == ["torch==2.15.0"] and why == {}
    (skimage,) = dropped
    assert skimage.distribution == "scikit-image"
    assert skimage.reason == (
        "scikit-image could not be installed: every release of it for Python 3.13 needs another numpy than "
        "Blender's numpy 2.2.4, and a second numpy would break Blender's own modules; Reconstruct (the mesh "
        "extraction) will not work without it"
    )
    # A transitive tested pin pip refuses is dropped, not the package that needs it.
    tested = deps.first_attempt(_requirements(deps), {"tifffile": "2026.3.3"}, deps.TESTED_PYTHON, "1.26.4")
    failure = deps.parse_resolution_failure(["ERROR: No matching distribution found for tifffile==2026.3.3"])
    after, dropped, why = deps.relax(tested, failure, deps.TESTED_PYTHON)
    assert after.specs() == tested.specs() and after.constraints == () and dropped == []


def test_untested_python_accepts_other_versions_but_not_missing_ones(deps) -> None:
    requirement = deps.Requirement("skimage", "scikit-image", "0.24.0")
    other = deps.ModuleStatus(requirement, "0.25.2", pins_apply=False)
    assert not other.needs_install
    assert other.describe() == f"scikit-image 0.25.2 (tested with 0.24.0 on Python {deps.python_text(deps.TESTED_PYTHON)})"
    assert deps.ModuleStatus(requirement, "0.25.2").needs_install  # on the tested Python the pin rules
    assert deps.ModuleStatus(requirement, None, pins_apply=False).needs_install


def test_install_on_untested_python_loosens_and_leaves_out(blender, deps, fake_python: Path, tmp_path: Path, monkeypatch) -> None:
    # The fake index has no scikit-image 0.24.0 (as PyPI for 3.13) and no pycolmap at all.
    monkeypatch.setenv("FAKE_PIP_NO_WHEEL", "scikit-image==0.24.0,pycolmap==4.2.1,pycolmap")
    todo = _requirements(deps) + [deps.Requirement("pycolmap", "pycolmap", "4.2.1")]
    target = tmp_path / "target"
    result = deps.install(str(fake_python), target, todo, python_version=(3, 13))
    resolves = [c for c in _calls(tmp_path) if "--dry-run" in c]
    assert [r[r.index("off") + 1:] for r in resolves] == [
        ["torch==2.15.0", "scikit-image==0.24.0", "pycolmap==4.2.1"],
        ["torch==2.15.0", "scikit-image", "pycolmap==4.2.1"],
        ["torch==2.15.0", "scikit-image", "pycolmap"],
        ["torch==2.15.0", "scikit-image"],
    ]
    assert result.packages == ["torch==2.15.0", "scikit-image==9.9.9", "sympy==1.14.0"]
    assert sorted(p.name for p in target.iterdir()) == ["scikit-image", "sympy", "torch"]
    assert [m.distribution for m in result.not_installed] == ["pycolmap"]
    summary = result.summary()
    assert "scikit-image 9.9.9 instead of the tested 0.24.0 (0.24.0 has no wheel for Python 3.13)" in summary
    assert ("pycolmap could not be installed: no release of it has a ready-built package (wheel) for Python 3.13 "
            "on this system; Estimate Poses and Refine Poses will not work without it") in summary


def test_install_without_network_says_pips_error_and_loosens_nothing(blender, deps, tmp_path: Path, monkeypatch) -> None:
    calls = []

    def offline(argv, stage, *args, **kwargs):
        calls.append(argv)
        raise deps.PipFailed("pip failed (exit code 1): ERROR: No matching distribution found for torch==2.15.0", PIP_OFFLINE)

    monkeypatch.setattr(deps, "run_pip", offline)
    with pytest.raises(deps.DependencyError, match=r"pip could not reach the package index \(pypi.org\).*NewConnectionError"):
        deps.install("/py", tmp_path / "t", _requirements(deps), python_version=(3, 13))
    assert len(calls) == 1
