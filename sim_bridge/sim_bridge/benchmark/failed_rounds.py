"""Rounds that Drake could not simulate (a RuntimeError from the simulation: a non-finite
pose in SceneGraph, SAP not converging), recorded once in `<out>/failed_rounds.json`.

A round is simulated in fixed time steps from fixed seeds, so on the same machine type
and code it fails the same way every time: a rerun of the benchmark does not run it again
(it cost up to minutes of CPU per rerun, and changed nothing), and `--report` lists it.
`--retry-failed` runs the recorded ones again (after a fix, or on another machine type);
one that then finishes leaves the list. Other errors (a bad model file, a missing object)
are not recorded: fixed, they are retried by the next run. Why 12 procedural rounds once
failed, and what fixed it: sim_bridge/doc/simulation-failures.md.
"""

from __future__ import annotations

import json
import pathlib

from gravgrasp_detector import atomic_files

FILE = "failed_rounds.json"


def key(method: str, mass_kg: float, scene_id: str) -> tuple:
    return method, float(mass_kg), scene_id


def load(out_dir) -> dict:
    """{key: record} of the failed rounds recorded in `out_dir` (none: {})."""
    path = pathlib.Path(out_dir) / FILE
    if not path.exists():
        return {}
    return {key(r["method"], r["mass_kg"], r["scene_id"]): r for r in json.loads(path.read_text())}


def save(out_dir, failed: dict) -> None:
    path = pathlib.Path(out_dir) / FILE
    records = [failed[k] for k in sorted(failed)]
    if records or path.exists():
        atomic_files.save_json(path, records)


def record(method: str, mass_kg: float, scene_id: str, model_sha256: str, error: str, machine: str) -> dict:
    return {"method": method, "mass_kg": float(mass_kg), "scene_id": scene_id, "model_sha256": model_sha256,
            "error": error, "machine": machine}


def report_lines(records: list) -> list:
    """results.md's lines on the failed rounds, by scene ([] when none failed)."""
    if not records:
        return []
    by_scene = {}
    for r in sorted(records, key=lambda r: (r["scene_id"], r["method"], r["mass_kg"])):
        by_scene.setdefault(r["scene_id"], []).append(r)
    lines = [f"Rounds Drake could not simulate ({len(records)}; recorded in {FILE}, not in the tables above, "
             "and not run again: `--retry-failed` retries them):", ""]
    for scene_id, rs in by_scene.items():
        rounds = ", ".join(f"{r['method']} {r['mass_kg']:g} kg" for r in rs)
        errors = sorted({r["error"] for r in rs})
        lines.append(f"- {scene_id}: {rounds}: {'; '.join(errors)}")
    return lines
