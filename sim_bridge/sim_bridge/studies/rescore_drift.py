"""Do rescored tables hold the rows their source held? `python -m sim_bridge.studies.rescore_drift TABLES`.

`datagen rescore` closes a source table's held rows again and copies its failed rows,
because the settings it changes (the drive, the ramps) act only after the hand has
settled. That holds for the settings, not for the code: the source tables were made by
an older commit, and a closing that is marginal (an object that barely stays between the
pads) can end the other way today. Both directions are counted here:

- held in the source, not held now: every rescored row, from the tables themselves;
- not held in the source, held now: a seeded sample of the copied failures, closed again
  with the table's settings (the closing alone decides "held"; no ramps), leaving out
  those that failed because the open hand met the object (geometry, the same in any
  commit) or because Drake met a non-finite value.

Prints both, and `held_now_of_copied_failures=` (the sample's fraction) last.
"""

import argparse
import json
import pathlib
import sys
import time

import numpy as np

from ..datagen.object_grasps import load_table
from ..datagen.object_sources import object_from_table
from ..datagen.rescored_tables import rescored_rows
from ..physics.contact import SimSettings
from ..physics.grasp_simulation import GraspSimulator, held_between_fingers

NOT_A_CLOSING = ("hand collides", "simulation error")  # failure reasons the code cannot change / cannot say


def drift(tables) -> dict:
    """One pass over rescored tables: {lost: rows held in the source and not now, held: rows
    held in the source, failures: [(table path, row)] of the failures the rescore copied that
    came from a closing}. Tables whose source cannot be read are left out."""
    out = {"lost": 0, "held": 0, "failures": []}
    for path in tables:
        with np.load(path) as t:
            marks = rescored_rows(t)
            if marks is None:
                continue
            (again, source_held), grasped = marks, t["grasped"].astype(bool)
            out["lost"] += int((source_held & ~grasped).sum())
            out["held"] += int(source_held.sum())
            out["failures"] += [(path, int(i)) for i in np.flatnonzero(~again & ~grasped)
                                if not str(t["reason"][i]).startswith(NOT_A_CLOSING)]
    return out


def held_after_closing(sim, X_object_tcp) -> bool:
    """The closing's verdict as `GraspSimulator.evaluate` gives it, without the ramps."""
    root, reason = sim.close(X_object_tcp)
    if reason:
        return False
    return held_between_fingers(sim.contact_links(root))


def reclose(sample, mesh_dirs):
    """[(table name, row, held now, what happened)] for each sampled (table path, row)."""
    out, sim, current = [], None, None
    for path, i in sample:
        if path != current:
            table = load_table(path)
            settings = SimSettings.from_record(json.loads(str(table["sim_settings"])))
            sim, current = GraspSimulator(object_from_table(table, mesh_dirs), settings), path
        try:
            held = held_after_closing(sim, table["X_object_tcp_candidate"][i].astype(float))
            out.append((pathlib.Path(path).stem, i, held, "held" if held else "not held"))
        except RuntimeError as e:  # Drake's non-finite state: counted as not held, as datagen does
            out.append((pathlib.Path(path).stem, i, False, f"simulation error: {str(e)[:60]}"))
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("tables", help="a directory of rescored tables (e.g. models/grasp_tables_v6), run from the "
                   "project root so that their sources (rescored_from) are found")
    p.add_argument("--meshes", action="append", default=[], help="where the tables' mesh files are")
    p.add_argument("--sample", type=int, default=240, help="copied failures to close again")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--out", default=None, help="JSON with each sampled row's outcome")
    args = p.parse_args(argv)
    d = pathlib.Path(args.tables)
    d = d / "objects" if (d / "objects").is_dir() else d
    tables = sorted(d.glob("*.npz"))
    counts = drift(tables)
    lost, held, candidates = counts["lost"], counts["held"], counts["failures"]
    if not held or not candidates:
        print(f"rescore_drift: no rescored table with a readable source in {d} (run from the project root)",
              file=sys.stderr)
        return 2
    rng = np.random.default_rng(args.seed)
    pick = sorted(rng.choice(len(candidates), min(args.sample, len(candidates)), replace=False))
    c0 = time.process_time()
    rows = reclose([candidates[k] for k in pick], tuple(args.meshes))
    now = sum(r[2] for r in rows)
    if args.out:
        pathlib.Path(args.out).write_text(json.dumps([dict(table=t, row=i, held=h, outcome=o) for t, i, h, o in rows],
                                                     indent=1))
    print(f"held in the source, not now: {lost} of {held} ({100 * lost / held:.1f}%), {len(tables)} tables")
    print(f"copied failures held now: {now} of {len(rows)} sampled ({100 * now / len(rows):.1f}%) of {len(candidates)} "
          f"closings that failed in the source; {time.process_time() - c0:.0f} CPU-s")
    print(f"held_now_of_copied_failures={now / len(rows):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
