"""Writing parameters into a cell's ROS 2 parameter file (the `--params-file` YAML)
without losing what a person wrote in it: the file is edited as text, only the named
`node: ros__parameters: name:` lines change (with a comment line above saying where the
value came from), everything else, comments included, stays byte for byte.

Values are written in flow style on one line; a parameter written in block style in the
file (a list over several lines) is replaced by one line. A parameter can also be removed
(a form the file no longer uses).
"""
from __future__ import annotations

import os
import pathlib
import re
import tempfile


def yaml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if ("." in repr(value) or "e" in repr(value)) else f"{value:.1f}"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        # ROS arrays are typed: floats must look like floats (0.0, not 0).
        return "[" + ", ".join(yaml_value(float(v) if isinstance(v, int) and not isinstance(v, bool) else v)
                               for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} as a ROS parameter")


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def _content(line: str) -> bool:
    stripped = line.strip()
    return bool(stripped) and not stripped.startswith("#")


def set_parameters(text: str, node: str, values: dict, comment: str | None = None) -> str:
    """`text` with node's parameters set to `values` (added where missing)."""
    lines = text.splitlines()
    header = re.compile(rf"^/?{re.escape(node)}:\s*(#.*)?$")
    start = next((i for i, line in enumerate(lines) if header.match(line)), None)
    if start is None:  # a new section at the end
        out = lines + ([""] if lines and lines[-1].strip() else []) + [f"{node}:", "  ros__parameters:"]
        for name, value in values.items():
            if comment:
                out.append(f"    # {comment}")
            out.append(f"    {name}: {yaml_value(value)}")
        return "\n".join(out) + "\n"
    end = next((i for i in range(start + 1, len(lines)) if _content(lines[i]) and _indent(lines[i]) == 0), len(lines))
    params = next((i for i in range(start + 1, end) if lines[i].strip().startswith("ros__parameters:")), None)
    if params is None:
        lines.insert(start + 1, "  ros__parameters:")
        params, end = start + 1, end + 1
    body = [i for i in range(params + 1, end) if _content(lines[i])]
    indent = _indent(lines[body[0]]) if body else _indent(lines[params]) + 2
    for name, value in values.items():
        new = f"{' ' * indent}{name}: {yaml_value(value)}"
        key = re.compile(rf"^ {{{indent}}}{re.escape(name)}:")
        at = next((i for i in range(params + 1, end) if key.match(lines[i])), None)
        if at is None:
            at = params + 1
            lines.insert(at, new)
            end += 1
        else:
            # drop a block-style continuation of the old value
            stop = at + 1
            while stop < end and (not lines[stop].strip() or _indent(lines[stop]) > indent) \
                    and not lines[stop].strip().startswith("#"):
                stop += 1
            while stop > at + 1 and not lines[stop - 1].strip():
                stop -= 1
            del lines[at + 1:stop]
            end -= stop - (at + 1)
            lines[at] = new
        if comment:
            marker = comment.split()[0]  # the writer, e.g. "calibrate_camera"
            if at > 0 and lines[at - 1].strip().startswith(f"# {marker}"):
                lines[at - 1] = f"{' ' * indent}# {comment}"
            else:
                lines.insert(at, f"{' ' * indent}# {comment}")
                end += 1
    return "\n".join(lines) + "\n"


def remove_parameters(text: str, node: str, names) -> str:
    """`text` without node's parameters `names` (block-style continuations and a comment
    line written above them by a tool, e.g. "# calibrate_camera ...", go too)."""
    lines = text.splitlines()
    header = re.compile(rf"^/?{re.escape(node)}:\s*(#.*)?$")
    start = next((i for i, line in enumerate(lines) if header.match(line)), None)
    if start is None:
        return text
    for name in names:
        end = next((i for i in range(start + 1, len(lines)) if _content(lines[i]) and _indent(lines[i]) == 0), len(lines))
        key = re.compile(rf"^ +{re.escape(name)}:")
        at = next((i for i in range(start + 1, end) if key.match(lines[i])), None)
        if at is None:
            continue
        indent, stop = _indent(lines[at]), at + 1
        while stop < end and lines[stop].strip() and _indent(lines[stop]) > indent and not lines[stop].strip().startswith("#"):
            stop += 1
        if at > start + 1 and re.match(r"^ *# (calibrate_camera|cell) ", lines[at - 1]):
            at -= 1
        del lines[at:stop]
    return "\n".join(lines) + "\n"


def write_parameters(path, updates: dict, comment: str | None = None, remove: dict | None = None) -> None:
    """updates: {node: {name: value}}; remove: {node: [name, ...]}; the file is replaced atomically."""
    path = pathlib.Path(path)
    text = path.read_text() if path.exists() else ""
    for node, names in (remove or {}).items():
        text = remove_parameters(text, node, names)
    for node, values in updates.items():
        text = set_parameters(text, node, values, comment)
    replace_file(path, text)


def replace_file(path, text: str) -> None:
    """Write `text` to `path` atomically (a temp file beside it, renamed)."""
    path = pathlib.Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)
