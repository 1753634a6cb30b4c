"""The manifest passes Blender's own extension validator and the build ships only the extension.

Uses Blender's CLI handler (`blender --command extension ...` without a Blender binary,
blender-notes.md section 1); it also checks tags against Blender's list, which the standalone
script would skip.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from conftest import REPO


def _extension_cli(args: list[str]) -> int:
    import bpy  # noqa: F401  (puts Blender's core add-ons, bl_pkg among them, on sys.path)
    from bl_pkg import bl_extension_cli

    return bl_extension_cli.cli_extension_handler(args)


def _blender_ext_script() -> Path:
    import bpy

    # bpy.__file__ is <site-packages>/bpy/<version>/scripts/modules/bpy/__init__.py
    scripts = Path(bpy.__file__).resolve().parents[2]
    script = scripts / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    assert script.is_file(), script
    return script


def test_manifest_fields() -> None:
    manifest = tomllib.loads((REPO / "blender_manifest.toml").read_text())
    assert manifest["id"] == "vortx"
    assert manifest["type"] == "add-on"
    assert tuple(int(x) for x in manifest["blender_version_min"].split(".")) <= (4, 2, 0)
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]
    assert "files" in manifest["permissions"]


def test_blender_validator_accepts_manifest(capfd: pytest.CaptureFixture[str]) -> None:
    assert _extension_cli(["validate", str(REPO)]) == 0
    out = capfd.readouterr()
    assert "ERROR" not in out.out + out.err


def test_blender_validator_rejects_unknown_tag(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    # Proves the validator call above can fail: the same manifest with a tag Blender does not know.
    bad = tmp_path / "bad"
    bad.mkdir()
    text = (REPO / "blender_manifest.toml").read_text()
    assert '"Camera"]' in text
    (bad / "blender_manifest.toml").write_text(text.replace('"Camera"]', '"Camera", "AI"]'))
    (bad / "__init__.py").write_text("def register():\n    pass\n\n\ndef unregister():\n    pass\n")
    assert _extension_cli(["validate", str(bad)]) != 0
    out = capfd.readouterr()
    assert '"AI"' in out.out + out.err


def test_standalone_validator_script_accepts_manifest() -> None:
    # The route CI uses without Blender's Python: the script does not import bpy.
    result = subprocess.run(
        [sys.executable, str(_blender_ext_script()), "validate", str(REPO)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_build_excludes_tests_and_dev_files(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    out_dir = tmp_path / "dist"
    out_dir.mkdir()
    assert _extension_cli(["build", "--source-dir", str(REPO), "--output-dir", str(out_dir)]) == 0
    (archive,) = out_dir.glob("vortx-*.zip")
    names = set(zipfile.ZipFile(archive).namelist())
    for required in ("blender_manifest.toml", "__init__.py", "vortx_blender/__init__.py", "operators/__init__.py", "ui/__init__.py", "engine/__init__.py"):
        assert required in names, required
    for name in names:
        top = name.split("/")[0]
        assert top not in {"tests", ".venv", ".git", "docs", "Makefile", "pytest.ini"}, name
        assert not name.endswith(".pyc") and "__pycache__" not in name, name
