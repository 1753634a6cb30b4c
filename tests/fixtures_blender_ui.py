"""A stand-in UILayout that checks every call the way Blender would (the panels' and the preferences'
draw() run headless against it): the function exists, keywords are its parameters, enum values are
valid, `prop` names a property of the data and `operator` a registered operator, whose returned
properties accept only that operator's properties.

Each recorded call is ("name", Bound) where Bound is the call's arguments (a dict) and `Bound.layout`
the Node it was drawn into: its kind (root, row, column, box, split), the attributes set on it
(use_property_split, alignment, ...) and its parent, so tests can tell how wide each text is drawn.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from types import ModuleType
from typing import Any, Iterator, Optional

SUB_LAYOUTS = ("row", "column", "box", "split", "column_flow", "grid_flow")


class Node:
    """One layout: its kind, the call's arguments, the attributes set on it, its parent, its items."""

    def __init__(self, kind: str, args: dict, parent: Optional["Node"]) -> None:
        self.kind, self.args, self.parent = kind, args, parent
        self.attributes: dict[str, Any] = {}
        self.items: list[Any] = []  # Bound calls and Nodes drawn into it, in order
        if parent is not None:
            parent.items.append(self)

    def inherited(self, name: str, default: Any = None) -> Any:
        """An attribute as Blender applies it: set here or on a layout above (use_property_split)."""
        node: Optional[Node] = self
        while node is not None:
            if name in node.attributes:
                return node.attributes[name]
            node = node.parent
        return default


class Bound(dict):
    """A call's arguments, with the layout it was drawn into."""

    layout: Node


class RecordedOperator:
    """What `layout.operator()` returns: the operator's properties, checked against its RNA."""

    def __init__(self, rna: Any, bound: Bound) -> None:
        object.__setattr__(self, "_rna", rna)
        object.__setattr__(self, "_bound", bound)
        bound["properties"] = {}

    def __setattr__(self, name: str, value: Any) -> None:
        assert name in self._rna.properties, f"operator {self._bound['operator']} has no property {name}"
        self._bound["properties"][name] = value


class RecordingLayout:
    def __init__(self, calls: list, node: Optional[Node] = None) -> None:
        object.__setattr__(self, "_calls", calls)
        object.__setattr__(self, "_node", node if node is not None else Node("root", {}, None))

    def __setattr__(self, name: str, value) -> None:
        import bpy

        assert name in bpy.types.UILayout.bl_rna.properties, f"UILayout has no attribute {name}"
        if name == "alignment":
            assert value in bpy.types.UILayout.bl_rna.properties["alignment"].enum_items.keys(), value
        self._node.attributes[name] = value
        self._calls.append(("set", {name: value}))

    def __getattr__(self, name: str):
        import bpy

        function = bpy.types.UILayout.bl_rna.functions.get(name)
        assert function is not None, f"UILayout has no function {name}"
        params = [p for p in function.parameters if not p.is_output]

        def call(*args, **kwargs):
            bound = Bound(zip((p.identifier for p in params), args))
            bound.update(kwargs)
            for key, value in bound.items():
                param = function.parameters.get(key)
                assert param is not None, f"UILayout.{name}() has no parameter {key}"
                if param.type == "ENUM" and isinstance(value, str) and value:
                    assert value in param.enum_items.keys(), f"{name}({key}={value!r}) is not a valid value"
            bound.layout = self._node
            if name in SUB_LAYOUTS:
                self._calls.append((name, bound))
                return RecordingLayout(self._calls, Node(name, dict(bound), self._node))
            self._node.items.append(bound)
            if name == "prop":
                assert bound["property"] in bound["data"].bl_rna.properties, f"no property {bound['property']}"
            self._calls.append((name, bound))
            if name == "operator":
                module, op = bound["operator"].split(".")
                rna = getattr(getattr(bpy.ops, module), op).get_rna_type()  # KeyError when not registered
                return RecordedOperator(rna, bound)
            return RecordingLayout(self._calls, Node(name, dict(bound), None))  # detached: not an item

        return call


@contextmanager
def job_paused_at(jobs: ModuleType, title: str, stage: str, done: int, total: int,
                  detail: Optional[str] = None) -> Iterator[Any]:
    """A job `title` (vortx_blender.jobs.Job) that has reported `stage` `done`/`total` (and the tile
    `detail`, if any) and waits there, polled once, so panels draw it as running; released on exit."""
    release, reported = threading.Event(), threading.Event()

    def work(progress, cancel):
        progress(stage, done, total)
        reported.set()
        release.wait(10)

    job = jobs.Job(title, work, detail=(lambda: detail) if detail is not None else None).start()
    try:
        reported.wait(5)
        job.poll()
        yield job
    finally:
        release.set()
        job.wait()

