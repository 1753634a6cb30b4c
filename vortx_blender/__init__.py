"""Blender-side core: scene settings, the job runner, building Blender data from engine results.

Modules here hold the logic that operators and panels use, written as functions that take data
(a scene, a Capture) rather than a UI context, so tests run them headless.
"""

from . import job_operator, preferences, properties, result, tile_overlay

_modules = (properties, job_operator, preferences, result, tile_overlay)


def register() -> None:
    for module in _modules:
        module.register()


def unregister() -> None:
    for module in reversed(_modules):
        module.unregister()
