"""`ros2 run sim_bridge bench_sim`: grasp evaluations per hour, both cores busy.

Evaluates power and precision grasps on a Ø65 x 200 mm, 0.5 kg cylinder (the paper's
test object) with hydroelastic contact at dt 1e-3 and 2e-3 (and point contact at 2e-3
for comparison), one simulation per worker
process (`--workers`, default: all cores), and measures how the score depends on the
force-ramp rate. Prints `name=value` lines; the last is `grasp_evals_per_hour=<n>` for
the default settings (hydroelastic, dt 2e-3, half power, half precision).
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from .grasp_simulation import GraspSimulator, SimSettings

# The paper: 12-18 h per object on an AWS m5.2xlarge (8 vCPU).
PAPER_CORE_HOURS_PER_OBJECT = (12 * 8, 18 * 8)
DEPTHS_M = {"power": -0.02, "precision": 0.0}  # cylinder axis along TCP z (see tests)


def _pose(depth_m, dx_m=0.0):
    X = np.eye(4)
    X[:3, :3] = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]])
    X[:3, 3] = [depth_m, 0, dx_m]
    return X


def _job(args):
    """One worker: build the diagram once, evaluate `n` grasps (small offsets along the
    cylinder axis so runs are not identical), return per-eval wall times and outcomes."""
    mode, dt, rate, n, contact = args
    from .objects import procedural_object

    cyl = procedural_object("cylinder", (0.065, 0.2), mass_kg=0.5)
    sim = GraspSimulator(cyl, SimSettings(time_step_s=dt, force_ramp_rate_n_s=rate, contact_model=contact))
    walls, cpus, modes, scores = [], [], [], []
    for k in range(n):
        t, c = time.perf_counter(), time.process_time()
        out = sim.evaluate(_pose(DEPTHS_M[mode], 0.002 * k))
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
        modes.append(out.mode)
        scores.append(out.scores_n)
    return mode, dt, rate, walls, modes, np.array(scores), contact, cpus


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench_sim", description=__doc__.split("\n\n")[0])
    p.add_argument("--evals", type=int, default=3, help="grasps per (mode, dt) per worker")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--skip-ramp-rates", action="store_true")
    a = p.parse_args(argv)

    rate0 = SimSettings.force_ramp_rate_n_s
    jobs = [(m, dt, rate0, a.evals, "hydroelastic") for dt in (1e-3, 2e-3) for m in ("precision", "power")]
    jobs += [(m, 2e-3, rate0, a.evals, "point") for m in ("precision", "power")]
    # every worker runs every configuration, so all cores are busy for the whole run
    work = [j for j in jobs for _ in range(a.workers)]
    # ramp-rate check at dt 1 ms, where scores have converged in dt (README)
    rates = (rate0 / 2, rate0, rate0 * 2)
    if not a.skip_ramp_rates:
        work += [(m, 1e-3, r, 1, "hydroelastic") for m in ("precision", "power") for r in rates]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as ex:
        results = list(ex.map(_job, work))
    total = time.perf_counter() - t0

    load = os.getloadavg()
    print(f"machine_cores={os.cpu_count()} workers={a.workers} "
          f"load_average_1_5min={load[0]:.1f},{load[1]:.1f} (other jobs inflate the times)")
    per = {}
    for mode, dt, rate, walls, modes, scores, contact, cpus in results:
        if rate != rate0 or len(walls) != a.evals:
            continue
        per.setdefault((contact, mode, dt), ([], [], []))
        per[(contact, mode, dt)][0].extend(walls)
        per[(contact, mode, dt)][1].extend(modes)
        per[(contact, mode, dt)][2].extend(cpus)
    for (contact, mode, dt), (walls, modes, cpus) in sorted(per.items()):
        ok = sum(m == mode for m in modes)
        s, c = float(np.mean(walls)), float(np.mean(cpus))
        name = f"{contact[:5]}_dt{dt:g}_{mode}"
        print(f"{name}_s_per_eval={s:.2f} cpu_s_per_eval={c:.2f}  ({ok}/{len(modes)} classified {mode})")
        print(f"{name}_evals_per_hour={a.workers * 3600 / s:.0f}")
    if not a.skip_ramp_rates:
        for mode in ("precision", "power"):
            by_rate = {r: sc[0] for m, d, r, _, _, sc, c, _ in results
                       if m == mode and d == 1e-3 and r in rates and c == "hydroelastic"}
            ref = by_rate[rate0]
            for r in rates:
                rel = (by_rate[r] - ref) / np.maximum(ref, 1e-9)
                print(f"ramp_dt0.001_{mode}_{r:.0f}Nps_scores_n={np.round(by_rate[r], 1).tolist()} "
                      f"max_rel_diff_vs_{rate0:.0f}={np.max(np.abs(rel)):.3f} min_score_n={by_rate[r].min():.1f}")
    default = [per[("hydroelastic", m, 2e-3)] for m in ("precision", "power")]
    s_mix = float(np.mean([np.mean(w) for w, _, _ in default]))
    c_mix = float(np.mean([np.mean(c) for _, _, c in default]))
    per_hour = a.workers * 3600 / s_mix
    lo, hi = PAPER_CORE_HOURS_PER_OBJECT
    print(f"core_seconds_per_eval={s_mix:.2f} cpu_seconds_per_eval={c_mix:.2f}")
    print(f"grasp_evals_per_hour_if_cores_were_ours={a.workers * 3600 / c_mix:.0f}")
    print(f"paper_budget_{lo}-{hi}_core_hours_buys_evals={lo * 3600 / s_mix:.0f}-{hi * 3600 / s_mix:.0f}")
    print(f"bench_wall_s={total:.0f}")
    print(f"grasp_evals_per_hour={per_hour:.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
