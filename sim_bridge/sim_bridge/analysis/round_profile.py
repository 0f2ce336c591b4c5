"""Where a clutter round's CPU goes: one committed round replayed (or one with no record,
e.g. one Drake could not simulate, run from its scene), its CPU and simulated time split
by phase (each phase's own, without the phases inside it).

    python -m sim_bridge.analysis.round_profile --results sim_bridge/results/heldout_v4_a47ba91 \\
        --method binary --weight 1.5 --scene packed_001 [--execution fast] [--cprofile 20]

Phases: the scene's build and first settle, the settle at the round's weight, the view
(render + TSDF), detection, the executor's motions by name (calibration, pregrasp, grasp =
the approach, lift, backing out), the finger waits, hold and open (`world.advance`), the
shake and the way home (`world.move_tcp`). `--cprofile N` adds the N functions with the
most own time (Drake's stepping shows as `AdvanceTo`). The last line is `round_cpu_s=`.
"""
from __future__ import annotations

import argparse
import collections
import cProfile
import io
import json
import pathlib
import pstats
import sys
import time

import torch

from ..benchmark.clearing import clear_table
from ..benchmark.methods import method_named
from ..benchmark.protocol import EXECUTION_SETTINGS, Protocol, weight_key, with_execution
from ..benchmark.rounds import RoundTask, make_cell


class PhaseClock:
    """CPU and simulated seconds per phase, exclusive of the phases nested in it."""

    def __init__(self, sim_time):
        self.sim_time, self.totals, self._stack = sim_time, collections.defaultdict(lambda: [0.0, 0.0, 0]), []

    def wrap(self, obj, attr, phase):
        """Time obj.attr under `phase` (a name, or a function of the call's args giving one)."""
        inner = getattr(obj, attr)

        def timed(*args, **kwargs):
            name = phase(args) if callable(phase) else phase
            t0, s0 = time.process_time(), self.sim_time()
            self._stack.append([0.0, 0.0])
            try:
                return inner(*args, **kwargs)
            finally:
                child_cpu, child_sim = self._stack.pop()
                cpu, sim = time.process_time() - t0, self.sim_time() - s0
                total = self.totals[name]
                total[0] += cpu - child_cpu
                total[1] += sim - child_sim
                total[2] += 1
                if self._stack:
                    self._stack[-1][0] += cpu
                    self._stack[-1][1] += sim
        setattr(obj, attr, timed)


def profile_round(results_dir, method, mass_kg, scene_id, execution=None, models_dir="models", cprofile=0):
    """-> (rows [(phase, cpu_s, sim_s, calls)], outcomes, total cpu_s, cProfile text or '')."""
    d = pathlib.Path(results_dir)
    rf = d / "rounds" / method / weight_key(mass_kg) / f"{scene_id}.json"
    # A round without a record (one Drake could not simulate: failed_rounds) runs from its scene.
    if not rf.is_file() and not (d / "scenes" / f"{scene_id}.json").is_file():
        raise ValueError(f"no committed round {rf}, and no scene {scene_id} in {d / 'scenes'}")
    config = json.loads((d / "config.json").read_text())
    protocol = Protocol(**config["protocol"])
    if execution:
        protocol = with_execution(protocol, execution)
    scene = json.loads((d / "scenes" / f"{scene_id}.json").read_text())
    task = RoundTask(method, str(method_named(method).locate(models_dir)), "", float(mass_kg), scene, protocol)
    torch.set_num_threads(1)
    t0 = time.process_time()
    cell, _ = make_cell(task)
    clock = PhaseClock(lambda: cell.world.time_s)
    clock.totals["build + first settle"] = [time.process_time() - t0, cell.world.time_s, 1]
    ex = cell.executor
    for obj, attr, phase in ((cell, "settle", "settle at the weight"), (cell, "observe", "view (render + TSDF)"),
                             (cell, "_detect", "detection"), (cell, "execute", "execute (bookkeeping)"),
                             (ex, "_move", lambda a: f"move: {a[0]}"), (ex, "_grip", lambda a: f"fingers: {a[2]}"),
                             (cell.world, "move_tcp", "shake and home (world.move_tcp)"),
                             (cell.world, "advance", "waits: fingers, hold, open (world.advance)")):
        clock.wrap(obj, attr, phase)
    profiler = cProfile.Profile() if cprofile else None
    if profiler:
        profiler.enable()
    cell.settle()
    cell.remove_fallen()
    record = clear_table(cell, len(cell.objects_on_table()), protocol.attempts_per_object)
    if profiler:
        profiler.disable()
    total = time.process_time() - t0
    text = ""
    if profiler:
        buf = io.StringIO()
        pstats.Stats(profiler, stream=buf).sort_stats("tottime").print_stats(cprofile)
        text = buf.getvalue()
    rows = sorted(((k, c, s, n) for k, (c, s, n) in clock.totals.items()), key=lambda r: -r[1])
    return rows, [a["outcome"] for a in record["attempts"]], total, text


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--results", required=True)
    p.add_argument("--method", required=True)
    p.add_argument("--weight", required=True, type=float)
    p.add_argument("--scene", required=True)
    p.add_argument("--execution", choices=sorted(EXECUTION_SETTINGS), help="default: the run's own")
    p.add_argument("--cprofile", type=int, default=0, metavar="N")
    args = p.parse_args(argv)
    try:
        rows, outcomes, total, text = profile_round(args.results, args.method, args.weight, args.scene,
                                                    args.execution, cprofile=args.cprofile)
    except (ValueError, KeyError, OSError) as e:
        print(f"round_profile: {e}", file=sys.stderr)
        return 2
    print(f"outcomes: {outcomes}")
    print("| phase | CPU s | share | simulated s | calls | CPU s per simulated s |\n|---|---|---|---|---|---|")
    for name, cpu, sim, calls in rows:
        if cpu >= 0.05:
            rate = f"{cpu / sim:.2f}" if sim > 0.01 else ""
            print(f"| {name} | {cpu:.1f} | {100 * cpu / total:.0f} % | {sim:.2f} | {calls} | {rate} |")
    if text:
        print(text)
    print(f"round_cpu_s={total:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
