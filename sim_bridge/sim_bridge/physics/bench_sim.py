"""`ros2 run sim_bridge bench_sim`: grasp evaluations per hour, both cores busy.

Evaluates power and precision grasps on a Ø65 x 200 mm, 0.5 kg cylinder (the paper's
test object), one simulation per worker process (`--workers`, default: all cores), with
hydroelastic contact at the fast defaults (dt 2 ms, 400 N/s) and at the label settings
(`SimSettings.for_labels()`: dt 1 ms, 1600 N/s), point contact for comparison, and
checks the ramp-rate dependence at dt 1 ms. Prints `name=value` lines, wall and CPU
time; the last is `grasp_evals_per_hour=<n>` for the label settings (half power, half
precision, wall time with both cores busy).
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from .contact import SimSettings
from .grasp_simulation import GraspSimulator
from .objects import procedural_object

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
    p.add_argument("--evals", type=int, default=2, help="grasps per (mode, setting) per worker")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--skip-ramp-rates", action="store_true")
    a = p.parse_args(argv)

    fast, labels = SimSettings(), SimSettings.for_labels()
    settings = [("hydro", fast.time_step_s, fast.force_ramp_rate_n_s),
                ("hydro", labels.time_step_s, labels.force_ramp_rate_n_s),
                ("point", fast.time_step_s, fast.force_ramp_rate_n_s)]
    contact = {"hydro": "hydroelastic", "point": "point"}
    jobs = [(m, dt, rate, a.evals, contact[c]) for c, dt, rate in settings for m in ("precision", "power")]
    # every worker runs every configuration, so all cores are busy for the whole run
    work = [j for j in jobs for _ in range(a.workers)]
    # ramp-rate check at the label time step (scores have converged in dt there)
    rates = (400.0, 800.0, 1600.0)
    if not a.skip_ramp_rates:
        work += [(m, labels.time_step_s, r, 1, "hydroelastic") for m in ("precision", "power") for r in rates]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as ex:
        results = list(ex.map(_job, work))
    total = time.perf_counter() - t0

    load = os.getloadavg()
    print(f"machine_cores={os.cpu_count()} workers={a.workers} "
          f"load_average_1_5min={load[0]:.1f},{load[1]:.1f} (other jobs inflate wall times)")
    per = {}
    for mode, dt, rate, walls, modes, scores, cm, cpus in results:
        if len(walls) != a.evals or (cm, dt, rate) not in {(contact[c], d, r) for c, d, r in settings}:
            continue
        w, m_, c_ = per.setdefault((cm, dt, rate, mode), ([], [], []))
        w.extend(walls), m_.extend(modes), c_.extend(cpus)
    for (cm, dt, rate, mode), (walls, modes, cpus) in sorted(per.items()):
        ok = sum(m == mode for m in modes)
        w, c = float(np.mean(walls)), float(np.mean(cpus))
        name = f"{cm[:5]}_dt{dt:g}_{rate:.0f}Nps_{mode}"
        print(f"{name}_s_per_eval={w:.2f} cpu_s_per_eval={c:.2f} "
              f"evals_per_hour={a.workers * 3600 / w:.0f} ({ok}/{len(modes)} classified {mode})")
    if not a.skip_ramp_rates:
        for mode in ("precision", "power"):
            by_rate = {r: sc[0] for m, d, r, _, _, sc, c, _ in results
                       if m == mode and d == labels.time_step_s and r in rates and len(sc) == 1
                       and c == "hydroelastic"}
            ref = by_rate[rates[0]]
            for r in rates:
                rel = np.abs(by_rate[r] - ref) / np.maximum(ref, 1e-9)
                print(f"ramp_dt{labels.time_step_s:g}_{mode}_{r:.0f}Nps_scores_n={np.round(by_rate[r], 1).tolist()} "
                      f"max_rel_diff_vs_{rates[0]:.0f}={rel.max():.3f}")

    def mix(dt, rate):
        both = [per[("hydroelastic", dt, rate, m)] for m in ("precision", "power")]
        return float(np.mean([np.mean(x[0]) for x in both])), float(np.mean([np.mean(x[2]) for x in both]))

    w_fast, c_fast = mix(fast.time_step_s, fast.force_ramp_rate_n_s)
    w_lab, c_lab = mix(labels.time_step_s, labels.force_ramp_rate_n_s)
    lo, hi = PAPER_CORE_HOURS_PER_OBJECT
    print(f"fast_defaults_evals_per_hour={a.workers * 3600 / w_fast:.0f} "
          f"(cpu-based {a.workers * 3600 / c_fast:.0f})")
    print(f"labels_wall_s_per_eval={w_lab:.2f} labels_cpu_s_per_eval={c_lab:.2f} "
          f"labels_evals_per_hour_cpu_based={a.workers * 3600 / c_lab:.0f}")
    print(f"paper_budget_{lo}-{hi}_core_hours_buys_label_evals={lo * 3600 / c_lab:.0f}-{hi * 3600 / c_lab:.0f} "
          f"(cpu-based)")
    print(f"bench_wall_s={total:.0f}")
    # last line: label settings (what data generation should use), both cores busy, wall
    print(f"grasp_evals_per_hour={a.workers * 3600 / w_lab:.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
