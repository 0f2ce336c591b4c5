"""Crash-safe file writes: write a temporary file beside the target, fsync, rename.

A reader (or a resumed run) sees either the old file or the complete new one,
never a partial file, even if the process is killed mid-write. Every file the project
writes for later (tables, scenes, rounds, checkpoints, models, plots) goes through here.
"""

import io
import json
import os
import pathlib
import tempfile

import numpy as np


def _replace_with(path, data: bytes):
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; outputs are shared data
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def save_npz(path, **arrays):
    """np.savez_compressed, atomically."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    _replace_with(path, buf.getvalue())


def save_json(path, obj):
    _replace_with(path, (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode())


def save_bytes(path, data: bytes):
    _replace_with(path, data)


def save_figure(path, fig, **savefig_kwargs):
    """A matplotlib figure (`fig.savefig`), atomically; the format follows the suffix."""
    buf = io.BytesIO()
    fig.savefig(buf, format=pathlib.Path(path).suffix.lstrip(".") or "png", **savefig_kwargs)
    _replace_with(path, buf.getvalue())


def save_torch(path, obj):
    """torch.save, atomically (torch is imported by the caller that has the object)."""
    import torch  # lazy: the other writers must not pull torch into data generation

    buf = io.BytesIO()
    torch.save(obj, buf)
    _replace_with(path, buf.getvalue())


def remove_stale_temporaries(directory):
    """Delete temporaries left by a killed writer (they are never valid outputs)."""
    for p in pathlib.Path(directory).rglob(".*.tmp"):
        try:
            p.unlink()
        except FileNotFoundError:
            pass
