"""The imports of a Python source file, read with `ast` (an import inside a function
counts), as absolute module names: what the layering tests check."""
import ast
import pathlib


def module_imports(path: pathlib.Path, source_root: pathlib.Path):
    """(absolute module name, line) for every import in `path`; `source_root` is the folder
    the top package sits in (relative imports resolve against path's place below it)."""
    package = list(path.relative_to(source_root).with_suffix("").parts[:-1])
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            if node.module is None:  # from . import a, b
                for alias in node.names:
                    yield f"{module}.{alias.name}", node.lineno
            else:
                yield module, node.lineno


def sub_package(path: pathlib.Path, package_dir: pathlib.Path):
    """The sub-package `path` sits in below `package_dir`, None for a top-level module."""
    parts = path.relative_to(package_dir).parts
    return parts[0] if len(parts) > 1 else None


def layering_violations(path: pathlib.Path, package_dir: pathlib.Path, allowed: dict, plumbing: set,
                        ros_modules: tuple) -> list:
    """The imports of `path` that break its package's layering, one line each: only the `ros`
    sub-package imports `ros_modules`; a sub-package imports itself, `plumbing` (top-level
    modules) and the sub-packages `allowed` names for it; plumbing imports no sub-package."""
    package, own, wrong = package_dir.name, sub_package(path, package_dir), []
    for module, line in module_imports(path, package_dir.parent):
        parts = module.split(".")
        if parts[0] in ros_modules and own != "ros":
            wrong.append(f"line {line}: {module} (only {package}.ros talks to ROS)")
        if parts[0] != package or len(parts) < 2 or parts[1] in plumbing:
            continue
        if own is None:
            wrong.append(f"line {line}: {module} (plumbing imports no sub-package)")
        elif parts[1] != own and parts[1] not in allowed[own]:
            wrong.append(f"line {line}: {module} ({own} may import {sorted(allowed[own]) or 'nothing'})")
    return wrong
