"""What a clutter round costs under the old and the new execution settings, side by side.

    make bench-round        # python -m sim_bridge.benchmark.bench_round

Runs a fixed set of committed rounds (their scenes, weights and models) whole, once under
"v4" (every run up to benchmark v4) and once under the new settings (default "fast"),
on two worker processes: each pair of runs shares the machine at the same time, so
neither has it to itself. Prints one line per round and run, then
`round_cpu_s_before=` and `round_cpu_s=` (medians, CPU seconds per round),
`attempt_cpu_s_before=`/`attempt_cpu_s=` (CPU seconds per attempt: a round under other
settings may take another number of attempts) and, last, `round_cpu_ratio=` (new / old
of the medians).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import sys

from gravgrasp_detector.perception.model_file import file_sha256

from ..parallel import make_executor, run_tasks
from . import run_files
from .methods import method_named
from .protocol import EXECUTION_SETTINGS, Protocol, weight_key, with_execution
from .rounds import RoundTask, run_round

# (results dir, method, weight kg, scene): short rounds of the held-out tuning meshes,
# both methods, a success, drops and a refusal among them.
ROUNDS = (
    ("sim_bridge/results/heldout_v4_a47ba91", "binary", 1.5, "packed_001"),
    ("sim_bridge/results/heldout_v4_a47ba91", "ours", 1.5, "packed_002"),
    ("sim_bridge/results/heldout_v4_a47ba91", "ours", 1.5, "pile_002"),
)


def tasks(settings: str, rounds=ROUNDS, models_dir="models") -> list:
    """[(label, RoundTask)] for each round under "v4" and under `settings`, interleaved."""
    out = []
    for results_dir, method, mass_kg, sid in rounds:
        d = pathlib.Path(results_dir)
        config = json.loads((d / "config.json").read_text())
        scene = run_files.scenes_file(d).get(sid)
        model = method_named(method).default_path(models_dir)
        for name in ("v4", settings):
            protocol = with_execution(Protocol(**config["protocol"]), name)
            out.append((name, RoundTask(method, str(model), file_sha256(model), float(mass_kg), scene, protocol)))
    return out


def _run(labelled):
    return run_round(labelled[1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--settings", default="fast", help=f"the new settings ({', '.join(EXECUTION_SETTINGS)})")
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    if args.settings not in EXECUTION_SETTINGS:
        print(f"bench_round: --settings {args.settings!r}: use one of {', '.join(EXECUTION_SETTINGS)}", file=sys.stderr)
        return 2
    try:
        jobs = tasks(args.settings)
    except (OSError, KeyError) as e:
        print(f"bench_round: the committed rounds it replays are missing ({e}): run it from the project root",
              file=sys.stderr)
        return 2
    results = {}

    def on_result(job, record):
        name, task = job
        results[(name, task.method, task.scene["scene_id"])] = record
        print(f"{name:12s} {task.method} {weight_key(task.mass_kg)} kg {task.scene['scene_id']}: "
              f"{record['cpu_s']:.1f} CPU-s, {record['sim_time_s']:.1f} s simulated, "
              f"{[a['outcome'] for a in record['attempts']]}", flush=True)

    with make_executor(args.workers) as ex:
        run_tasks(ex, _run, jobs, on_result, desc="rounds", progress=False)

    def of(name):
        rs = [r for (n, *_), r in results.items() if n == name]
        return (statistics.median(r["cpu_s"] for r in rs),
                sum(r["cpu_s"] for r in rs) / max(1, sum(len(r["attempts"]) for r in rs)))

    (before, per_attempt_before), (after, per_attempt) = of("v4"), of(args.settings)
    print(f"settings={args.settings}")
    print(f"round_cpu_s_before={before:.1f}")
    print(f"round_cpu_s={after:.1f}")
    print(f"attempt_cpu_s_before={per_attempt_before:.1f}")
    print(f"attempt_cpu_s={per_attempt:.1f}")
    print(f"round_cpu_ratio={after / before:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
