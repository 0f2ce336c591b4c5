"""Why did that attempt fail? `python -m sim_bridge.analysis.replay --results DIR --method M
--weight KG --scene ID` runs one recorded benchmark round again and prints, per attempt,
what lay in the open hand's closing region (between the pads, palm face to finger tips;
detection.CLOSING_REGION_TCP) at the grasp it executed:

- `observed`: the on-or-behind-surface TSDF voxels the detector saw there (the ones its
  closing-region check counts), with their extent in the TCP frame [mm] (x across the pads,
  y along the closing stroke, z along the approach: more is deeper);
- `objects`: for each object really there (its rendered mesh, 4,000 surface samples), how
  many samples and their extent [mm];
- `recorded`: the outcome the committed round has for that attempt, and `replayed`: what
  happened now. Rounds run in simulated time with fixed seeds, so the two agree (and the
  poses too) when the model file and the code are the round's; the last line counts
  `matched=`.

`--attempts N` stops after attempt N; `--dump DIR` writes each attempt's TSDF and pose
(`<n>.npz`: grid, voxel_size_m, origin, pose) for closer looks. The model must be the one
the round ran (its sha256 is in the round file); `--model` gives it when models/ holds
another, e.g. `git show <commit>:models/gravgrasp.pt > old.pt`.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np
import torch
import trimesh

from gravgrasp_detector.perception.detection import CLOSING_REGION_TCP, surface_voxel_centres
from gravgrasp_detector.perception.model_file import file_sha256

from ..benchmark import run_files
from ..benchmark.clearing import clear_table
from ..benchmark.methods import METHODS
from ..benchmark.protocol import Protocol, weight_key
from ..benchmark.rounds import RoundTask, make_cell

MESH_SAMPLES = 4000


class _Enough(Exception):
    """Raised from the wrapped execute once the asked-for attempts are done."""


def in_closing_region(X_task_tcp, points_task) -> tuple:
    """(mask of the points inside the open hand's closing region, points in the TCP frame)."""
    q = (np.asarray(points_task, float) - X_task_tcp[:3, 3]) @ X_task_tcp[:3, :3]
    lo, hi = CLOSING_REGION_TCP
    return np.all((q >= lo) & (q <= hi), axis=1), q


def _extent_mm(q):
    return {"min": np.round(q.min(axis=0) * 1000).astype(int).tolist(),
            "max": np.round(q.max(axis=0) * 1000).astype(int).tolist()}


def closing_region_contents(X_task_tcp, tsdf, object_points) -> dict:
    """What the detector saw and what was really in the closing region at X_task_tcp.
    tsdf: (grid, voxel_size_m, origin); object_points: {name: (M, 3) surface samples, task frame}."""
    inside, q = in_closing_region(X_task_tcp, surface_voxel_centres(*tsdf))
    observed = {"voxels": int(inside.sum()), **(_extent_mm(q[inside]) if inside.any() else {})}
    objects = {}
    for name, points in object_points.items():
        inside, q = in_closing_region(X_task_tcp, points)
        if inside.any():
            objects[name] = {"samples": int(inside.sum()), **_extent_mm(q[inside])}
    return {"observed": observed, "objects": objects}


def mesh_samples(mesh) -> np.ndarray:
    """MESH_SAMPLES points on a mesh's surface, in its own frame (fixed seed)."""
    return trimesh.sample.sample_surface(mesh, MESH_SAMPLES, seed=0)[0]


class SurfaceSamples:
    """Each object's mesh sampled once (its own frame, by `sample`), posed where the world
    has it now."""

    def __init__(self, world, sample=mesh_samples):
        self.world, self._sample, self._local = world, sample, {}

    def now(self) -> dict:
        out = {}
        for name, (mesh, X) in self.world.object_meshes().items():
            if name not in self._local:
                self._local[name] = self._sample(mesh)
            out[name] = self._local[name] @ X[:3, :3].T + X[:3, 3]
        return out


def recorded_round(results_dir, method, mass_kg, scene_id) -> dict:
    """A committed round's record; ValueError (one line) where the run has none."""
    recorded = run_files.rounds_file(results_dir).get(method, mass_kg, scene_id)
    if recorded is None:
        raise ValueError(f"no round of {method} at {weight_key(mass_kg)} kg on {scene_id} in {results_dir}: see its "
                         f"{run_files.ROUNDS} for the methods, weights and scenes run")
    return recorded


def rebuild_cell(results_dir, recorded, model_path) -> tuple:
    """(cell, protocol) of a committed round as the benchmark built it: the run's scene and
    protocol, the model file the round ran (checked by its sha256), one torch thread.
    ValueError (one line) for another model file."""
    results_dir = pathlib.Path(results_dir)
    if file_sha256(model_path) != recorded["model_sha256"]:
        raise ValueError(f"{model_path} is not the model this round ran ({recorded['method']} "
                         f"{recorded['mass_kg']} kg {recorded['scene_id']}, sha256 {recorded['model_sha256'][:12]}…): "
                         "pass --model with that file, e.g. from `git log -- models/` and `git show COMMIT:PATH`")
    config = json.loads((results_dir / "config.json").read_text())
    scene = run_files.scenes_file(results_dir).get(recorded["scene_id"])
    protocol = Protocol(**config["protocol"])
    torch.set_num_threads(1)
    cell, _ = make_cell(RoundTask(recorded["method"], str(model_path), recorded["model_sha256"],
                                  float(recorded["mass_kg"]), scene, protocol))
    return cell, protocol


def replay_round(results_dir, method, mass_kg, scene_id, model_path=None, max_attempts=None, dump_dir=None,
                 report=print) -> list:
    """Replay one committed round; `report` gets one dict per attempt. -> those dicts.
    ValueError (one line) when the round, its scene or its model file is not there."""
    recorded = recorded_round(results_dir, method, mass_kg, scene_id)
    if model_path is None:
        if method not in METHODS:
            raise ValueError(f"method {method!r} has no registered file: pass --model")
        model_path = METHODS[method].default_path()
    model_path = pathlib.Path(model_path)
    if not model_path.is_file():
        raise ValueError(f"model file {model_path} not found")
    cell, protocol = rebuild_cell(results_dir, recorded, model_path)
    if dump_dir is not None:
        pathlib.Path(dump_dir).mkdir(parents=True, exist_ok=True)
    done, execute, samples = [], cell.execute, SurfaceSamples(cell.world)

    def observed_execute(grasp, tsdf):
        contents = closing_region_contents(np.asarray(grasp.pose), tsdf, samples.now())
        result = execute(grasp, tsdf)  # Refused propagates: clear_table tries the next grasp
        n = len(done) + 1
        before = recorded["attempts"][n - 1] if n <= len(recorded["attempts"]) else {}
        entry = {"attempt": n, "recorded": before.get("outcome", "(none)"), "replayed": result["outcome"],
                 "same_pose": bool(before) and np.allclose(before["pose"], result["pose"], atol=2e-6),
                 **{k: result[k] for k in ("score_n", "validness", "rank_key")}, **contents,
                 "reason": result["reason"]}
        if dump_dir is not None:
            grid, voxel_size_m, origin = tsdf
            np.savez_compressed(pathlib.Path(dump_dir) / f"{n}.npz", grid=grid, voxel_size_m=voxel_size_m,
                                origin=origin, pose=np.asarray(grasp.pose))
        done.append(entry)
        report(entry)
        if max_attempts is not None and n >= max_attempts:
            raise _Enough
        return result

    cell.execute = observed_execute
    cell.settle()
    cell.remove_fallen()
    try:
        clear_table(cell, len(cell.objects_on_table()), protocol.attempts_per_object)
    except _Enough:
        pass
    return done


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--results", required=True, help="a benchmark output directory, e.g. sim_bridge/results/heldout")
    p.add_argument("--method", required=True, help="e.g. ours, binary, ours_expected")
    p.add_argument("--weight", required=True, type=float, help="object weight of the round [kg]")
    p.add_argument("--scene", required=True, help="scene id, e.g. packed_000")
    p.add_argument("--model", help="the model file the round ran (default: the method's file in models/)")
    p.add_argument("--attempts", type=int, help="stop after this attempt")
    p.add_argument("--dump", help="write <n>.npz (TSDF, pose) per attempt here")
    args = p.parse_args(argv)
    try:
        done = replay_round(args.results, args.method, args.weight, args.scene, args.model, args.attempts,
                            args.dump, report=lambda entry: print(json.dumps(entry), flush=True))
    except ValueError as e:
        print(f"replay_round: {e}", file=sys.stderr)
        return 2
    matched = sum(d["recorded"] == d["replayed"] and d["same_pose"] for d in done)
    print(f"replayed={len(done)} matched={matched}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
