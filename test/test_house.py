"""The house rules, enforced: short functions, short modules, no hand-made import paths.

Every non-test Python file of the repository (packages, tools, scripts) is read as source, so
the rules hold for code that no test imports too. A test file is one under a ``test``/``tests``
folder, or named ``test_*.py`` / ``conftest.py``: tests may be long, code may not.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 600
#: Folders that hold no source of ours: the build, the venv, run outputs.
SKIPPED = {".git", ".venv", "build", "install", "log", "runs", "__pycache__", ".setup-logs"}


def _is_test(path: Path, root: Path) -> bool:
    parts = path.relative_to(root).parts
    return (
        "test" in parts
        or "tests" in parts
        or path.name.startswith("test_")
        or path.name == "conftest.py"
    )


def source_files(root: Path = ROOT) -> list[Path]:
    """The repository's non-test Python files."""
    found = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).parts
        if SKIPPED.intersection(rel) or _is_test(path, root):
            continue
        found.append(path)
    return found


def violations(path: Path, root: Path = ROOT) -> list[str]:
    """Each broken rule of one file, as 'PLACE: what (limit)'."""
    text = path.read_text(encoding="utf-8")
    rel = path.relative_to(root)
    found = []
    lines = len(text.splitlines())
    if lines > MAX_MODULE_LINES:
        found.append(f"{rel}: module of {lines} lines (limit {MAX_MODULE_LINES})")
    tree = ast.parse(text, filename=str(rel))
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            length = node.end_lineno - node.lineno + 1
            if length > MAX_FUNCTION_LINES:
                found.append(
                    f"{rel}:{node.lineno}: function {node.name} of {length} lines "
                    f"(limit {MAX_FUNCTION_LINES})"
                )
        if isinstance(node, ast.Attribute) and node.attr == "path":
            base = node.value
            if isinstance(base, ast.Name) and base.id == "sys":
                found.append(f"{rel}:{node.lineno}: sys.path used (install the package instead)")
        imports_path = isinstance(node, ast.ImportFrom) and node.module == "sys"
        if imports_path and any(alias.name == "path" for alias in node.names):
            found.append(f"{rel}:{node.lineno}: sys.path used (install the package instead)")
    return found


def test_the_code_keeps_the_house_rules():
    files = source_files()
    assert len(files) > 100, "the scan found too few files: is ROOT right?"
    broken = [v for path in files for v in violations(path)]
    assert not broken, "house rules broken:\n" + "\n".join(broken)


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        ("def f():\n" + "    x = 1\n" * 99 + "    return x\n", "function f of 101 lines"),
        ("x = 1\n" * 601, "module of 601 lines (limit 600)"),
        ("import sys\nsys.path.insert(0, '.')\n", "sys.path used"),
        ("from sys import path\npath.append('.')\n", "sys.path used"),
    ],
)
def test_a_planted_break_is_found_and_named(tmp_path, body, expected):
    planted = tmp_path / "pkg" / "planted.py"
    planted.parent.mkdir()
    planted.write_text(body)
    assert source_files(tmp_path) == [planted]
    found = violations(planted, tmp_path)
    assert len(found) == 1
    assert found[0].startswith("pkg/planted.py")
    assert expected in found[0]


def test_tests_and_build_outputs_are_not_scanned(tmp_path):
    for rel in ("pkg/test/test_long.py", "pkg/conftest.py", ".venv/lib/x.py", "build/y.py"):
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("def f():\n" + "    pass\n" * 100)
    assert source_files(tmp_path) == []


def test_an_eighty_line_function_is_allowed(tmp_path):
    path = tmp_path / "ok.py"
    path.write_text("def f():\n" + "    x = 1\n" * 78 + "    return x\n")
    assert violations(path, tmp_path) == []


def duplicate_test_modules(root: Path = ROOT) -> list[str]:
    """Test modules that share a file name across the suite's folders: pytest imports them by
    their base name (the folders are not packages), so the second fails to collect."""
    by_name: dict[str, list[str]] = {}
    for path in sorted(root.rglob("test_*.py")):
        rel = path.relative_to(root)
        if SKIPPED.intersection(rel.parts):
            continue
        by_name.setdefault(path.name, []).append(str(rel))
    return [f"{name}: {', '.join(paths)}" for name, paths in by_name.items() if len(paths) > 1]


def test_test_module_names_are_unique():
    assert duplicate_test_modules() == []


def test_a_planted_duplicate_test_module_is_named(tmp_path):
    for folder in ("pkg_a/test", "pkg_b/test"):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "test_same.py").write_text("def test_x():\n    pass\n")
    (tmp_path / "build" / "pkg_a").mkdir(parents=True)
    (tmp_path / "build" / "pkg_a" / "test_same.py").write_text("")
    assert duplicate_test_modules(tmp_path) == [
        "test_same.py: pkg_a/test/test_same.py, pkg_b/test/test_same.py"
    ]


def test_the_modules_handed_out_first_are_modules_of_the_suite():
    """conftest.LONGEST_MODULES names test modules that exist (a renamed one would fall back
    among the short ones and end the run late), each once."""
    tree = ast.parse((ROOT / "conftest.py").read_text())
    (value,) = [
        node.value
        for node in tree.body
        if isinstance(node, ast.Assign) and ast.unparse(node.targets[0]) == "LONGEST_MODULES"
    ]
    longest = ast.literal_eval(value)  # (read, not imported: a second conftest shadows it)
    names = {path.name for path in ROOT.rglob("test_*.py") if not SKIPPED.intersection(path.parts)}
    assert sorted(set(longest) - names) == []
    assert len(set(longest)) == len(longest)
