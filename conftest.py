"""pytest, at the repository root.

The root is the Blender extension's package: its __init__.py imports relatively (`.engine`), so it
can only be imported under a package name. pytest would make the root folder a Package and import
that __init__.py under the folder's name, which fails for a clone in a folder that is not a Python
identifier (`mktemp -d` gives `tmp.XXXX`). The root is collected as a plain folder instead; tests
import `engine` from the root (pytest.ini pythonpath) and load the extension package themselves.
"""

from __future__ import annotations

import pytest


class RootIsNotATestPackage:
    # A plain plugin, not a conftest hook: pytest asks the root folder's parent which collector to
    # make for the root, and conftest hooks only answer for folders at or below their own.
    @staticmethod
    def pytest_collect_directory(path, parent):
        if path == parent.config.rootpath:
            return pytest.Dir.from_parent(parent, path=path)
        return None


def pytest_configure(config):
    config.pluginmanager.register(RootIsNotATestPackage(), "vortx-root-is-not-a-test-package")
