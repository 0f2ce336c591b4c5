"""The driver proper (robotiq_driver's top-level modules) imports nothing from
robotiq_driver.emulator: the emulator stands in for the hardware, the driver must not
need it. Read from the source with `ast`, so an import inside a function counts."""

import ast
import pathlib

import pytest

PACKAGE_DIR = pathlib.Path(__file__).resolve().parents[2] / "robotiq_driver" / "robotiq_driver"


def _imported_modules(path):
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:  # relative to the top-level package
                module = "robotiq_driver." + module if module else "robotiq_driver"
            yield module
            yield from (f"{module}.{alias.name}" for alias in node.names)


@pytest.mark.parametrize("path", sorted(PACKAGE_DIR.glob("*.py")), ids=lambda p: p.name)
def test_the_driver_does_not_import_the_emulator(path):
    wrong = [m for m in _imported_modules(path) if m.startswith("robotiq_driver.emulator")]
    assert not wrong, f"{path.name} imports {wrong}"
