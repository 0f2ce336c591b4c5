"""A run's records on disk: one JSON record per line in one file (a benchmark run's
rounds.jsonl and scenes.jsonl, a study's rounds.jsonl), sorted by key, so that a committed
run is a few files, not a directory per round.

Every new record rewrites the whole file atomically (atomic_files: temporary + fsync +
rename), so a killed run loses at most the records still in flight. Runs written before
this kept one JSON file per record under a folder (rounds/<method>/<kg>/<scene>.json,
scenes/<scene>.json); those files are read beside the packed file and win where both
hold a record, since a job on older code may still be writing them. `convert` packs them:

    python -m sim_bridge.benchmark.run_files convert RUN_DIR [RUN_DIR ...]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from gravgrasp_detector import atomic_files

ROUNDS = "rounds.jsonl"
SCENES = "scenes.jsonl"
ROUND_KEY = ("method", "mass_kg", "scene_id")  # a benchmark round
SCENE_KEY = ("scene_id",)


def _key_of(record: dict, fields: tuple) -> tuple:
    return tuple(float(record[f]) if f == "mass_kg" else record[f] for f in fields)


class RecordFile:
    """The records of `path` (JSON lines) and of the per-record files under `folder`
    (the older layout), by key (the values of `fields`; mass_kg as a float)."""

    def __init__(self, path, fields: tuple, folder=None):
        self.path, self.fields = pathlib.Path(path), tuple(fields)
        self.folder = pathlib.Path(folder) if folder is not None else None
        self._records, self._files = {}, {}  # key: record; key: its per-record file
        if self.path.exists():
            for line in self.path.read_text().splitlines():
                if line.strip():
                    record = json.loads(line)
                    self._records[_key_of(record, self.fields)] = record
        if self.folder is not None and self.folder.is_dir():
            for f in sorted(self.folder.rglob("*.json")):
                record = json.loads(f.read_text())
                key = _key_of(record, self.fields)
                self._records[key] = record  # a per-record file wins: older code may still write it
                self._files[key] = f

    def __len__(self) -> int:
        return len(self._records)

    def get(self, *key):
        return self._records.get(_key_of(dict(zip(self.fields, key)), self.fields))

    def records(self) -> list:
        """Every record, sorted by key."""
        return [self._records[k] for k in sorted(self._records)]

    def put(self, *records: dict) -> None:
        """Add or replace `records` and rewrite the file once; a per-record file of their keys goes."""
        keys = [_key_of(r, self.fields) for r in records]
        self._records.update(zip(keys, records))
        self._write()
        for key in keys:
            stale = self._files.pop(key, None)
            if stale is not None:
                stale.unlink(missing_ok=True)

    def pack(self) -> int:
        """Write every record into the file and delete the per-record files; how many were packed."""
        self._write()
        for f in self._files.values():
            f.unlink(missing_ok=True)
        packed, self._files = len(self._files), {}
        if self.folder is not None and self.folder.is_dir():
            for d in sorted((p for p in self.folder.rglob("*") if p.is_dir()), reverse=True) + [self.folder]:
                if not any(d.iterdir()):
                    d.rmdir()
        return packed

    def _write(self) -> None:
        lines = [json.dumps(r, sort_keys=True, separators=(",", ":")) + "\n" for r in self.records()]
        atomic_files.save_bytes(self.path, "".join(lines).encode())


def rounds_file(run_dir) -> RecordFile:
    """A benchmark run's rounds: rounds.jsonl and any rounds/<method>/<kg>/<scene>.json."""
    run_dir = pathlib.Path(run_dir)
    return RecordFile(run_dir / ROUNDS, ROUND_KEY, run_dir / "rounds")


def scenes_file(run_dir) -> RecordFile:
    """A benchmark run's scenes: scenes.jsonl and any scenes/<scene>.json."""
    run_dir = pathlib.Path(run_dir)
    return RecordFile(run_dir / SCENES, SCENE_KEY, run_dir / "scenes")


def study_rounds_file(out_dir, fields: tuple) -> RecordFile:
    """A study's records by `fields`: rounds.jsonl and any rounds/**/<scene>.json."""
    out_dir = pathlib.Path(out_dir)
    return RecordFile(out_dir / ROUNDS, fields, out_dir / "rounds")


def convert(run_dir) -> dict:
    """Pack a benchmark run's per-round and per-scene files into rounds.jsonl and scenes.jsonl."""
    return {"rounds": rounds_file(run_dir).pack(), "scenes": scenes_file(run_dir).pack()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    c = sub.add_parser("convert", help="pack a benchmark run's rounds/ and scenes/ into rounds.jsonl and scenes.jsonl")
    c.add_argument("runs", nargs="+", help="benchmark run directories (each with a config.json)")
    args = p.parse_args(argv)
    for run in map(pathlib.Path, args.runs):
        if not (run / "config.json").is_file():
            print(f"run_files: {run} holds no benchmark run (no config.json): give the --out of a run", file=sys.stderr)
            return 2
        n = convert(run)
        print(f"{run}: packed {n['rounds']} round files into {ROUNDS}, {n['scenes']} scene files into {SCENES}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
