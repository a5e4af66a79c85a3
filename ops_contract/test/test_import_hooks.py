"""after_import: a function runs when a module loads, once, as its latest request made it."""

from __future__ import annotations

import sys

import pytest
from ops_contract.import_hooks import after_import


@pytest.fixture
def module_on_path(tmp_path, monkeypatch):
    """The name of a module that exists on sys.path and is not loaded yet."""
    name = f"hooked_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{name}.py").write_text("VALUE = 7\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield name
    sys.modules.pop(name, None)


def _request(name: str, seen: list, tag: str) -> None:
    # One function (one qualified name) per call, as a command run twice in a process asks.
    after_import(name, lambda module: seen.append((tag, module.VALUE)))


def test_the_function_waits_for_the_import_and_runs_once(module_on_path):
    seen: list = []
    _request(module_on_path, seen, "first")
    assert seen == [] and module_on_path not in sys.modules
    __import__(module_on_path)
    __import__(module_on_path)
    assert seen == [("first", 7)]


def test_a_second_request_of_the_same_function_takes_the_first_ones_place(module_on_path):
    seen: list = []
    _request(module_on_path, seen, "first")
    _request(module_on_path, seen, "latest")
    __import__(module_on_path)
    assert seen == [("latest", 7)]


def test_other_functions_all_run_and_a_loaded_module_runs_it_at_once(module_on_path):
    seen: list = []
    _request(module_on_path, seen, "first")
    after_import(module_on_path, lambda module: seen.append(("other", module.VALUE)))
    __import__(module_on_path)
    assert sorted(seen) == [("first", 7), ("other", 7)]
    _request(module_on_path, seen, "now")
    assert seen[-1] == ("now", 7)
