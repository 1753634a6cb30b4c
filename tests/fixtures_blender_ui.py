"""A stand-in UILayout that checks every call the way Blender would (the panels' and the preferences'
draw() run headless against it): the function exists, keywords are its parameters, enum values are
valid, `prop` names a property of the data and `operator` a registered operator."""

from __future__ import annotations


class RecordingLayout:
    def __init__(self, calls: list) -> None:
        object.__setattr__(self, "_calls", calls)

    def __setattr__(self, name: str, value) -> None:
        import bpy

        assert name in bpy.types.UILayout.bl_rna.properties, f"UILayout has no attribute {name}"
        self._calls.append(("set", {name: value}))

    def __getattr__(self, name: str):
        import bpy

        function = bpy.types.UILayout.bl_rna.functions.get(name)
        assert function is not None, f"UILayout has no function {name}"
        params = [p for p in function.parameters if not p.is_output]

        def call(*args, **kwargs):
            bound = dict(zip((p.identifier for p in params), args))
            bound.update(kwargs)
            for key, value in bound.items():
                param = function.parameters.get(key)
                assert param is not None, f"UILayout.{name}() has no parameter {key}"
                if param.type == "ENUM" and isinstance(value, str) and value:
                    assert value in param.enum_items.keys(), f"{name}({key}={value!r}) is not a valid value"
            if name == "prop":
                assert bound["property"] in bound["data"].bl_rna.properties, f"no property {bound['property']}"
            if name == "operator":
                module, op = bound["operator"].split(".")
                getattr(getattr(bpy.ops, module), op).get_rna_type()  # KeyError when not registered
            self._calls.append((name, bound))
            return RecordingLayout(self._calls)

        return call
