"""devtools/ is for a checkout only (blender_manifest.toml leaves it out of the zip): nothing that
ships may import it, or the installed extension would fail where the checkout works."""

from __future__ import annotations

import tomllib

from conftest import REPO
from fixtures_import_graph import GRAPH


def test_nothing_the_extension_ships_imports_devtools() -> None:
    shipped = [m for m in GRAPH if m.split(".")[0] in ("engine", "vortx_blender", "operators", "ui")]
    assert "devtools.demo.pipeline" in GRAPH and "engine.eval.against_truth" in GRAPH["devtools.demo.pipeline"]
    assert not {m: sorted(d for d in GRAPH[m] if d.startswith("devtools")) for m in shipped
                if any(d.startswith("devtools") for d in GRAPH[m])}


def test_the_manifest_leaves_devtools_out() -> None:
    manifest = tomllib.loads((REPO / "blender_manifest.toml").read_text())
    assert "/devtools/" in manifest["build"]["paths_exclude_pattern"]
