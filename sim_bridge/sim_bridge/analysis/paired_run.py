"""A benchmark run that pairs new methods with committed rounds, so that only the new
methods cost CPU: `python -m sim_bridge.analysis.paired_run --source RUN --out DIR
--methods ours,binary` copies into DIR what the benchmark needs to resume RUN there:
its config.json, excluded_objects.json and scenes, and the rounds (and any rounds Drake
could not simulate, failed_rounds.json) of the named methods (benchmark.run_files). The benchmark, run into
DIR with RUN's options and the new methods, then draws no scene and reruns none of the
copied rounds (their model's sha256 matches), and `--report` with every method compares
them all per scene, paired (heldout_v4_sure was made so, by hand).

Refuses, copying nothing, when a copied round was run with another model file than the
one the method has now (its model_sha256): it would be rerun, not paired. Idempotent:
files and records already there and equal (as JSON; config.json apart from what a run adds
to it, "hands" and "machines") are kept; a different one is refused, not overwritten.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from gravgrasp_detector import atomic_files
from gravgrasp_detector.perception.model_file import file_sha256

from ..benchmark import failed_rounds, run_files
from ..benchmark.methods import MethodFileMissing, method_named
from ..benchmark.protocol import execution_of

RUN_FILES = ("config.json", "excluded_objects.json")
ADDED_BY_A_RUN = ("hands", "machines")  # config.json keys the benchmark writes as methods join


class PairedRunError(ValueError):
    """The source run cannot be paired into the output directory (the message says why)."""


def comparable_config(config: dict) -> dict:
    """config.json without what a run adds as methods join, its execution settings filled
    in as the benchmark does for runs from before they were recorded."""
    config = {k: v for k, v in config.items() if k not in ADDED_BY_A_RUN}
    return {**config, "protocol": {**config["protocol"], **execution_of(config["protocol"])}}


def _same(source: pathlib.Path, dest: pathlib.Path, is_config: bool) -> bool:
    a, b = json.loads(source.read_text()), json.loads(dest.read_text())
    return comparable_config(a) == comparable_config(b) if is_config else a == b


def rounds_of(source: pathlib.Path, method: str) -> list:
    """The rounds of `method` in the run `source`, sorted by weight and scene."""
    return [r for r in run_files.rounds_file(source).records() if r["method"] == method]


def check_models(source: pathlib.Path, methods, models_dir) -> None:
    """PairedRunError unless every round of `methods` in `source` ran with the model file
    each method has now (under `models_dir`)."""
    for name in methods:
        try:
            path = method_named(name).locate(models_dir)
        except MethodFileMissing as e:
            raise PairedRunError(f"{name}'s model file is needed to check its rounds: {e}") from None
        sha = file_sha256(path)
        ran = {r.get("model_sha256") for r in rounds_of(source, name)}
        ran |= {r["model_sha256"] for k, r in failed_rounds.load(source).items() if k[0] == name}
        other = sorted(ran - {sha}, key=str)
        if other:
            raise PairedRunError(
                f"{source}: the rounds of {name} were run with another model (sha256 {str(other[0])[:12]}...) than "
                f"{path} (sha256 {sha[:12]}...): those rounds would be rerun, not paired; restore the model they "
                "were run with, or rerun them")


def prepare(source, out, methods, models_dir="models", note=print) -> dict:
    """Copy what pairs the rounds of `methods` in the run `source` with a run in `out`
    (the module doc). Returns {"copied": n, "kept": n} files and records; PairedRunError
    saying what is wrong, with nothing copied, otherwise."""
    source, out = pathlib.Path(source), pathlib.Path(out)
    if not (source / "config.json").is_file():
        raise PairedRunError(f"{source} holds no benchmark run (no config.json): give the --out of a run")
    if source.resolve() == out.resolve():
        raise PairedRunError(f"--out {out} is the source run itself: give another directory")
    check_models(source, methods, models_dir)
    pairs = [(source / f, out / f) for f in RUN_FILES if (source / f).is_file()]
    scenes = run_files.scenes_file(source).records()
    rounds = []
    for name in methods:
        found = rounds_of(source, name)
        if not found:
            note(f"paired_run: {source} has no rounds of {name}: it will be missing in {out}")
        rounds += found
    out_scenes, out_rounds = run_files.scenes_file(out), run_files.rounds_file(out)
    there = [(s, out_scenes.get(s["scene_id"])) for s in scenes]
    there += [(r, out_rounds.get(r["method"], r["mass_kg"], r["scene_id"])) for r in rounds]
    differ = [str(dest) for src, dest in pairs if dest.exists() and not _same(src, dest, src == source / "config.json")]
    differ += [f"{out}'s record of {' '.join(str(a[k]) for k in ('method', 'mass_kg', 'scene_id') if k in a)}"
               for a, b in there if b is not None and a != b]
    if differ:
        raise PairedRunError(f"{differ[0]} differs from its source in {source} ({len(differ)} such files or records): "
                             f"{out} holds another run; use another --out, or delete it to start over")
    copied = 0
    for src, dest in pairs:
        if not dest.exists():
            atomic_files.save_bytes(dest, src.read_bytes())
            copied += 1
    new_scenes = [s for s, b in there[:len(scenes)] if b is None]
    new_rounds = [r for r, b in there[len(scenes):] if b is None]
    if new_scenes:
        out_scenes.put(*new_scenes)
    if new_rounds:
        out_rounds.put(*new_rounds)
    copied += len(new_scenes) + len(new_rounds)
    # rounds Drake could not simulate count as run: copied, so that they are not rerun either
    gave_up = {k: r for k, r in failed_rounds.load(source).items() if k[0] in methods}
    if gave_up:
        failed_rounds.save(out, {**failed_rounds.load(out), **gave_up})
    return {"copied": copied, "kept": len(pairs) + len(there) - copied}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--source", required=True, help="the committed run whose rounds are paired, e.g. "
                   "sim_bridge/results/heldout_v4")
    p.add_argument("--out", required=True, help="the new run's directory (the benchmark's --out)")
    p.add_argument("--methods", required=True, help="comma-separated methods whose rounds are copied")
    p.add_argument("--models-dir", default="models")
    args = p.parse_args(argv)
    try:
        counts = prepare(args.source, args.out, [m for m in args.methods.split(",") if m], args.models_dir)
    except ValueError as e:  # PairedRunError, or method_named's unknown method
        print(f"paired_run: {e}", file=sys.stderr)
        return 2
    print(f"paired_run: {args.out}: {counts['copied']} files and records copied from {args.source}, {counts['kept']} already there")
    return 0


if __name__ == "__main__":
    sys.exit(main())
