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
