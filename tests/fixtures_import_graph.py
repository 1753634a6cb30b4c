"""The project's imports, read from the source with `ast`, for the layering tests.

Every import counts: module level, inside functions (a lazy import only hides a cycle from Python,
not from the reader), under TYPE_CHECKING, relative and absolute. `from package import name` points
at the submodule `package.name` when there is one, otherwise at the package's __init__.py.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("engine", "vortx_blender", "operators", "ui", "devtools")


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for package in PACKAGES for p in (ROOT / package).rglob("*.py")}


@dataclass(frozen=True)
class ImportSite:
    """One import statement of a project file."""

    importer: str
    line: int
    end_line: int
    column: int
    modules: frozenset[str]  # the project modules it loads
    externals: frozenset[str]  # top-level names of the other modules it loads (torch, bpy, ...)
    in_function: bool
    under_type_checking: bool


def _targets(node: ast.Import | ast.ImportFrom, importer: str) -> tuple[set[str], set[str]]:
    path = MODULES[importer]
    package = importer if path.name == "__init__.py" else importer.rsplit(".", 1)[0]
    if isinstance(node, ast.Import):
        names = {alias.name for alias in node.names}
    else:
        if node.level:
            parts = package.split(".")
            target = ".".join(parts[: len(parts) - (node.level - 1)] + ([node.module] if node.module else []))
        else:
            target = node.module or ""
        if target.startswith("vortx."):  # the extension's own name, as Blender imports it
            target = target[len("vortx."):]
        submodules = {f"{target}.{alias.name}" for alias in node.names} & MODULES.keys()
        names = set(submodules)
        if len(submodules) < len(node.names):
            names.add(target)
            lazy = lazy_names(target)
            for alias in node.names:  # a name the package's __getattr__ imports on first use
                names |= lazy.get(alias.name, set())
    project = {n for n in names if n in MODULES and n != importer}
    externals = {n.split(".")[0] for n in names if n.split(".")[0] not in PACKAGES and n != "vortx"}
    return project, externals


def lazy_names(package: str) -> dict[str, set[str]]:
    """name -> the modules a package's module-level `__getattr__` imports to give that name (PEP 562)."""
    if package not in MODULES:
        return {}
    lazy: dict[str, set[str]] = {}
    for node in ast.parse(MODULES[package].read_text(encoding="utf-8")).body:
        if isinstance(node, ast.FunctionDef) and node.name == "__getattr__":
            for inner in ast.walk(node):
                if isinstance(inner, ast.ImportFrom) and inner.level == 1 and inner.module:
                    for alias in inner.names:
                        lazy.setdefault(alias.asname or alias.name, set()).add(f"{package}.{inner.module}")
    return lazy


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def import_sites(importer: str) -> list[ImportSite]:
    tree = ast.parse(MODULES[importer].read_text(encoding="utf-8"))
    sites: list[ImportSite] = []

    def visit(node: ast.AST, in_function: bool, type_checking: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                project, externals = _targets(child, importer)
                sites.append(ImportSite(importer, child.lineno, child.end_lineno or child.lineno, child.col_offset,
                                        frozenset(project), frozenset(externals),
                                        in_function, type_checking))
            elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                visit(child, True, type_checking)
            elif isinstance(child, ast.If) and _is_type_checking(child.test):
                for statement in child.body:
                    visit(ast.Module(body=[statement], type_ignores=[]), in_function, True)
                for statement in child.orelse:
                    visit(ast.Module(body=[statement], type_ignores=[]), in_function, type_checking)
            else:
                visit(child, in_function, type_checking)

    visit(tree, False, False)
    return sites


SITES = {m: import_sites(m) for m in MODULES}
GRAPH = {m: set().union(*(s.modules for s in SITES[m])) for m in MODULES}


def _parents(module: str) -> set[str]:
    """The packages whose __init__.py Python runs before `module`."""
    parts = module.split(".")
    return {".".join(parts[:i]) for i in range(1, len(parts))} & MODULES.keys()


def loaded_at_import(module: str) -> tuple[set[str], set[str]]:
    """(project modules, external top-level modules) that `import module` really runs: module-level
    imports only, followed through the project, parent packages included."""
    seen: set[str] = set()
    externals: set[str] = set()
    todo = [module]
    while todo:
        current = todo.pop()
        if current in seen:
            continue
        seen.add(current)
        todo.extend(_parents(current))
        for site in SITES[current]:
            if not site.in_function and not site.under_type_checking:
                todo.extend(site.modules)
                externals |= site.externals
    return seen, externals


def import_cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """The strongly connected sets of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[frozenset[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                members = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    members.add(member)
                    if member == node:
                        break
                if len(members) > 1:
                    cycles.append(frozenset(members))
    return cycles
