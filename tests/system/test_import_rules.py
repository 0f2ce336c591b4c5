"""Imports sit at the top of each module (issue 18). An import inside a function is
allowed only where a heavy or optional dependency makes loading it late worth it, and
then the function says why with a `# lazy: <reason>` comment, on the import's line or
anywhere above it inside the function (one comment covers the function's imports).
Read from the source with `ast` and `tokenize`, so nothing is imported."""

import ast
import io
import pathlib
import tokenize

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
PACKAGES = ("sim_bridge/sim_bridge", "gravgrasp_detector/gravgrasp_detector", "robotiq_driver/robotiq_driver")
MARKER = "# lazy:"


def _modules():
    return sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*.py"))


def _marker_lines(source: str) -> set:
    return {tok.start[0] for tok in tokenize.generate_tokens(io.StringIO(source).readline)
            if tok.type == tokenize.COMMENT and tok.string.startswith(MARKER)}


def unmarked_imports(source: str, filename: str = "<source>"):
    """(line, import text) for every import inside a function with no `# lazy:` comment
    between the innermost function's `def` and the import's last line."""
    markers = _marker_lines(source)
    lines = source.splitlines()
    found = []

    def visit(node, function):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                visit(child, child)
                continue
            if function is not None and isinstance(child, (ast.Import, ast.ImportFrom)):
                if not any(function.lineno <= m <= child.end_lineno for m in markers):
                    found.append((child.lineno, lines[child.lineno - 1].strip()))
            visit(child, function)

    visit(ast.parse(source, filename), None)
    return found


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_in_function_imports_say_why(path):
    wrong = [f"{path.relative_to(ROOT)}:{line}: {text}" for line, text in unmarked_imports(path.read_text(), str(path))]
    assert not wrong, ("imports inside functions: move them to the top of the module, or say why they must load "
                       f"late with a '{MARKER} <reason>' comment on or above the line:\n" + "\n".join(wrong))


def test_the_check_sees_an_unmarked_import():
    source = ("import os\n\n"
              "def plain():\n    import json\n    return json\n\n"
              "def commented():\n    # lazy: heavy\n    import numpy\n    import scipy\n\n"
              "def on_the_line():\n    import torch  # lazy: heavy\n\n"
              "def outer():\n    # lazy: this comment is not inside inner\n    def inner():\n        import yaml\n")
    assert [line for line, _ in unmarked_imports(source)] == [4, 18]
