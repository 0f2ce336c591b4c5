"""A directory built once per pytest run and shared by the run's xdist workers: the
first test that needs it builds it under a file lock, every later one (in any test file,
on either worker) reuses it. For Drake-made data that several test files read, which
costs tens of CPU-seconds to make; the tests only read it (or copy it to change it)."""
import os
import pathlib
import shutil

from filelock import FileLock


def shared_dir(tmp_path_factory, name: str, build) -> pathlib.Path:
    """The run-wide directory `name`, filled by build(path) once. Under xdist it sits in the
    run's base directory, beside the workers' own (popen-gw0, ...); without xdist, in this
    session's base directory."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    path = root / name
    with FileLock(str(path) + ".lock"):
        if not (path / ".built").exists():
            shutil.rmtree(path, ignore_errors=True)  # a build that failed part way
            path.mkdir()
            build(path)
            (path / ".built").touch()
    return path
