"""Run a function right after a module is imported, without importing it here.

A package that must act on a heavy dependency (register an environment with gymnasium, limit
torch's threads) but should not load it itself asks :func:`after_import`: the function runs at
once if the module is already loaded, else the moment some later import finishes loading it.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys
from collections.abc import Callable
from types import ModuleType


class _AfterImport(importlib.abc.MetaPathFinder):
    """Finds nothing itself: on the first import of ``name`` it leaves sys.meta_path, lets the
    finders after it find the module, and wraps its loader so that ``callback`` runs once the
    module has executed."""

    def __init__(self, name: str, callback: Callable[[ModuleType], None], key: str) -> None:
        self.name, self.callback, self.key = name, callback, key

    def find_spec(self, fullname, path=None, target=None):
        if fullname != self.name:
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None:
            return spec
        exec_module = spec.loader.exec_module

        def exec_then_call(module):
            exec_module(module)
            self.callback(module)

        spec.loader.exec_module = exec_then_call
        return spec


def after_import(name: str, callback: Callable[[ModuleType], None]) -> None:
    """Call ``callback(module)`` once the top-level module ``name`` is loaded: now, if it is,
    else right after its first import. A request with the same function as a waiting one (by
    its module and qualified name: a package imported again, a command run again in one
    process) takes its place: the function runs once, as the latest request made it (a
    closure's values are the latest run's)."""
    if name in sys.modules:
        callback(sys.modules[name])
        return
    key = f"{name}:{callback.__module__}.{callback.__qualname__}"
    for finder in sys.meta_path:
        if isinstance(finder, _AfterImport) and finder.key == key:
            finder.callback = callback
            return
    sys.meta_path.insert(0, _AfterImport(name, callback, key))
