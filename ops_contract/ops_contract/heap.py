"""The heavy imports' objects kept out of the garbage collector's walks.

torch and stable-baselines3 (with the pandas, matplotlib and tensorboard that it imports, and
the sympy of torch._dynamo, loaded at a training run's first optimizer step) leave about 375,000
objects that live as long as the process. Every full collection walks them all, and so does the
one the interpreter makes as it exits: a process that trained 300 steps spent about 6.5 s of
CPU, 1.4 s of it at exit (measured 2026-11-29 on the 2-core machine, ``train`` of
td3 at N = 2). :func:`freeze_after_heavy_imports` calls :func:`gc.freeze` (the use it is made
for: after the imports of a process) the moment each of them has loaded, which takes that time
off, here about 1.5 s of the 6.5. Objects made afterwards are collected as before, their
finalizers run at exit as before (a gc.freeze() at the end of the process would skip them:
ops_contract/test/test_heap.py); only the modules' own objects, which live until the process
ends anyway, are never walked again.

The nodes (:func:`~ops_contract.ros_interface.run_node`) and the CLIs that load or train models
(``train``, ``evaluate``, ``distill``, ``realism_sweep``, the benchmark's runs, ``ops-bench``)
call it first; a process that imports neither module is not touched.
"""

from __future__ import annotations

import gc
from types import ModuleType

from .import_hooks import after_import

#: The modules after whose import the heap is frozen (torch itself is loaded by the first).
HEAVY_MODULES = ("stable_baselines3", "torch._dynamo")


def _freeze(_module: ModuleType) -> None:
    gc.freeze()


def freeze_after_heavy_imports() -> None:
    """Freeze the heap (:func:`gc.freeze`) once each of :data:`HEAVY_MODULES` has loaded: now
    for one already loaded, else right after its import."""
    for name in HEAVY_MODULES:
        after_import(name, _freeze)
