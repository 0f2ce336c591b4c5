"""Point the ros-jazzy wheels' exported CMake files at this interpreter.

The wheels were built under /opt/python/cp311-cp311 and their `*Export.cmake` files
carry that builder's Python and numpy include paths; `rosidl_generate_interfaces`
fails on them until they name this venv's paths. Idempotent; run after every install.
"""
import pathlib
import re
import sys
import sysconfig

import numpy

PREFIX = pathlib.Path(sys.prefix)
BUILDER_NUMPY = re.compile(r"/opt/python/cp311-cp311/lib/python3\.11/site-packages/numpy/[\w/]*include")
BUILDER_PYTHON = re.compile(r"/opt/python/cp311-cp311/include/python3\.11")


def main() -> int:
    changed = 0
    for path in (PREFIX / "share").rglob("*.cmake"):
        text = path.read_text(errors="surrogateescape")
        if "/opt/python/cp311-cp311" not in text:
            continue
        fixed = BUILDER_NUMPY.sub(numpy.get_include(), text)
        fixed = BUILDER_PYTHON.sub(sysconfig.get_paths()["include"], fixed)
        if fixed != text:
            path.write_text(fixed, errors="surrogateescape")
            changed += 1
    print(f"repair_wheel_cmake: {changed} CMake files repointed to {PREFIX}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
