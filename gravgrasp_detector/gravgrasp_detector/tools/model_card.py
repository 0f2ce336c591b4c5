"""Model cards: `ros2 run gravgrasp_detector model_card RUN_DIR --model models/gravgrasp.pt`.

Writes `<model dir>/<model stem>.md` (e.g. models/gravgrasp.md) from a training output
directory (RUN_DIR: model.pt, history.json, training_curve.png as `train` writes them):
- Model: file, sha256, metadata (architecture, rotation representation, target, TSDF).
- Data: scenes and labels the run used (from the model's metadata), and the dataset
  summary of sim_bridge's `data_report` over the grasp tables and the scene files.
  The tables are --tables, or the `objects_dir` that `datagen scenes` recorded in
  scenes/manifest.json. data_report runs as a separate process: sim_bridge depends on
  this package, so this package does not import sim_bridge.
- Training: the command line, training time and machine as `train` recorded them, and
  the training curve, copied beside the card (<model stem>_training_curve.png): the run
  directory is usually under out/, which a clone does not have.
- Validation metrics: final and best epoch of history.json.
- Calibration (with --calibration, repeatable): `score_calibration` reports side by side,
  e.g. this model's and the shipped model's on the same validation scenes: validness
  precision and recall at the threshold, precision at equal recalls, AUROC, score MAE and
  Spearman per mode, and where
  the first pick of a scene lands (a held label, a known failure) by score, validness x
  score and validness.
- Qualitative check: the PNGs of `make qualitative` (out/qualitative/<model stem>/)
  and a paragraph for what a person saw in them. That paragraph (between the
  human-notes markers) is kept when the card is regenerated.
"""

import argparse
import datetime
import json
import math
import os
import pathlib
import re
import statistics
import subprocess
import sys
import tempfile

from .. import atomic_files
from ..perception import model_file

HUMAN_START, HUMAN_END = "<!-- human-notes: start -->", "<!-- human-notes: end -->"
HUMAN_PLACEHOLDER = (
    "_Not written yet._ Look at the PNGs above and write here what you saw, as the issue asks: "
    "is the score higher where power grasps fit (around the cylinder and the box at z = 0.08 m) "
    "than for fingertip grasps near the top edges? Does validness reject grasps that would "
    "collide (palm into the other object, into the table) or need more than the 85 mm stroke "
    "(across the box's 100 mm side; the paper's x = 0, y = ±0.05 m at z = 0.08 m)? Are the "
    "approach arrows plausible on the occluded side (y = 0 slice, behind the cylinder)?"
)
# (history.json key, label, better) of the validation metrics on the card
METRICS = (
    ("val_validness_precision", "validness precision (at 0.5)", max),
    ("val_validness_recall", "validness recall (at 0.5)", max),
    ("val_validness_auroc", "validness AUROC", max),
    ("val_score_mae_n", "score MAE [N] (valid voxels)", min),
    ("val_rotation_error_deg", "rotation error [deg] (valid voxels, 180° twin)", min),
    ("val_loss_total", "validation loss (total)", min),
)
SLICE_PNGS = ("slice_z150mm.png", "slice_z080mm.png", "slice_y000mm.png", "depth.png")


# the first-pick rankings of score_calibration's top_picks, as the card names them
PICK_RANKINGS = (("score", "score"), ("expected_score", "validness × score"), ("validness", "validness"))


class CardError(RuntimeError):
    """Input the card cannot be written from; the message says what to do."""


def load_history(run_dir):
    path = pathlib.Path(run_dir) / "history.json"
    try:
        history = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise CardError(f"{path} is missing or unreadable ({err}): give the --out directory of a "
                        "finished `ros2 run gravgrasp_detector train` run") from None
    if not isinstance(history, list) or not history:
        raise CardError(f"{path} has no epochs: the run has not finished an epoch")
    return history


def best_and_final(history):
    """{key: (final value, best value, best epoch)}; NaN epochs are skipped for the best."""
    out = {}
    for key, _, better in METRICS:
        values = [(h.get(key, math.nan), h["epoch"]) for h in history]
        finite = [(v, e) for v, e in values if isinstance(v, (int, float)) and math.isfinite(v)]
        best = better(finite, key=lambda ve: ve[0]) if finite else (math.nan, None)
        out[key] = (values[-1][0], best[0], best[1])
    return out


def tables_dir_for(data_dir, tables=None):
    """The grasp tables behind the scenes: --tables, or scenes/manifest.json's objects_dir."""
    if tables:
        return pathlib.Path(tables)
    for manifest in (pathlib.Path(data_dir) / "scenes" / "manifest.json", pathlib.Path(data_dir) / "manifest.json"):
        if manifest.is_file():
            objects_dir = json.loads(manifest.read_text()).get("objects_dir")
            if objects_dir:
                return pathlib.Path(objects_dir)
    return None


def data_summary(data_dir, tables_dir):
    """Run sim_bridge's data_report over the tables + scenes -> (text, {objects, grasps,
    power_fraction}). data_report wants DIR/objects and DIR/scenes: a temporary
    directory of two symlinks puts the separately stored tables and scenes there."""
    tables_dir = pathlib.Path(tables_dir).resolve()
    if (tables_dir / "objects").is_dir():
        tables_dir = tables_dir / "objects"
    data_dir = pathlib.Path(data_dir).resolve()
    scenes_dir = data_dir / "scenes" if (data_dir / "scenes").is_dir() else data_dir
    with tempfile.TemporaryDirectory(prefix="model_card_") as tmp:
        os.symlink(tables_dir, pathlib.Path(tmp) / "objects")
        os.symlink(scenes_dir, pathlib.Path(tmp) / "scenes")
        proc = subprocess.run([sys.executable, "-m", "sim_bridge.datagen.data_report", tmp,
                               "--png", str(pathlib.Path(tmp) / "report.png")],
                              capture_output=True, text=True)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        hint = " (source ros_ws/env.sh: sim_bridge is not on the path)" if "No module named" in last else ""
        raise CardError(f"sim_bridge data_report failed on tables {tables_dir} + scenes {scenes_dir}: {last}{hint}")
    lines = [line for line in proc.stdout.splitlines() if not line.startswith("histograms:")]
    numbers = dict(line.split("=", 1) for line in lines if re.fullmatch(r"\w+=[\d.]+", line))
    return "\n".join(lines), numbers


def _fmt(value, digits=3):
    if value is None:
        return "—"
    if isinstance(value, float):
        return "n/a" if not math.isfinite(value) else f"{value:.{digits}g}"
    return str(value)


def _duration(seconds):
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d} (h:mm:ss, {seconds:.0f} s)"


def _link(path, card_dir):
    """Markdown link to `path` from the card, shown as the path given."""
    return f"[{path}]({os.path.relpath(os.path.abspath(path), os.path.abspath(card_dir))})"


def _epoch_spread(history) -> str:
    """'; median …, slowest … (epoch k)' from the cumulative wall_s of each epoch: the
    mean hides a slow epoch (a cold first epoch, a machine shared with other jobs)."""
    walls = [h.get("wall_s") for h in history]
    if len(walls) < 2 or any(w is None for w in walls):
        return ""
    per = [float(b) - float(a) for a, b in zip([0.0] + walls[:-1], walls)]
    slowest = max(range(len(per)), key=per.__getitem__)
    return f"; median {statistics.median(per):.1f} s, slowest {per[slowest]:.1f} s (epoch {history[slowest]['epoch']})"


def curve_beside_card(run_dir, card_path):
    """(the run's training_curve.png, where the card keeps its copy)."""
    card_path = pathlib.Path(card_path)
    return pathlib.Path(run_dir) / "training_curve.png", card_path.with_name(f"{card_path.stem}_training_curve.png")


def human_notes(existing_card):
    """The paragraph a person wrote into an existing card, or the placeholder."""
    if existing_card.is_file():
        text = existing_card.read_text()
        if HUMAN_START in text and HUMAN_END in text:
            notes = text.split(HUMAN_START, 1)[1].split(HUMAN_END, 1)[0].strip()
            if notes:
                return notes
    return HUMAN_PLACEHOLDER


def load_calibration(path) -> dict:
    """A score_calibration JSON (calibration.json); CardError naming what is wrong."""
    try:
        report = json.loads(pathlib.Path(path).read_text())
        for keys in (("validness", "precision"), ("validness", "recall"), ("modes", "all"), ("top_picks",)):
            value = report
            for key in keys:  # the keys the card reads
                value = value[key]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise CardError(f"--calibration {path}: not a score_calibration report ({type(err).__name__}: {err}); "
                        "give the calibration.json that `score_calibration --out DIR` writes") from None
    return report


def calibration_lines(reports: list, paths: list) -> list:
    """Markdown: score_calibration reports side by side, one column each."""
    def pick_rate(r, ranking, where):
        first = r["top_picks"].get(ranking, {}).get("1")
        if not first:
            return "—"
        return f"{first[where] / max(1, first['label'] + first['negative'] + first['neither']):.2f}"

    def mode(r, m, key, digits):
        v = r["modes"].get(m, {}).get(key)
        return "—" if v is None else f"{v:.{digits}f}"

    # precision where every model has the same recall (reports made before it have none: a dash)
    recalls = next((list(r["validness"]["precision_at_recall"]) for r in reports
                    if "precision_at_recall" in r["validness"]), [])
    header = [f"`{r.get('model', '?')}` on `{r.get('data', '?')}` ({r.get('scenes', '?')} scenes, {r.get('split', '?')})"
              for r in reports]
    rows = [("validness precision / recall (at its threshold)",
             [f"{r['validness']['precision']:.3f} / {r['validness']['recall']:.3f} ({r['validness'].get('threshold', '?')})"
              for r in reports]),
            ("validness AUROC", [f"{r['validness'].get('auroc', math.nan):.3f}" for r in reports])]
    if recalls:
        rows.insert(1, (f"validness precision at equal recall {' / '.join(recalls)}",
                        [" / ".join(f"{r['validness']['precision_at_recall'][q]:.3f}" for q in recalls)
                         if set(recalls) <= set(r["validness"].get("precision_at_recall", {})) else "—"
                         for r in reports]))
    for m in ("all", "power", "precision"):
        rows.append((f"score MAE [N], {m}", [mode(r, m, "mae_n", 2) for r in reports]))
        rows.append((f"score Spearman, {m}", [mode(r, m, "spearman", 3) for r in reports]))
    for where, what in (("label", "on a held label"), ("negative", "on a known failure")):
        rows.append((f"first pick {what}, by " + " / ".join(n for _, n in PICK_RANKINGS),
                     [" / ".join(pick_rate(r, key, where) for key, _ in PICK_RANKINGS) for r in reports]))
    lines = ["## Calibration", "",
             "`python -m gravgrasp_detector.tools.score_calibration` reports ("
             + ", ".join(f"`{p}`" for p in paths) + "): predicted against simulated scores on the "
             "validation scenes, per grasp mode, and where each scene's first pick lands.", "",
             "| measure | " + " | ".join(header) + " |", "| --- |" + " --- |" * len(reports)]
    lines += [f"| {name} | " + " | ".join(cells) + " |" for name, cells in rows]
    return lines + [""]


def render_card(run_dir, model_path, card_path, qualitative_dir, tables=None, argv=None, recipes=None,
                calibrations=()):
    """The card as Markdown text."""
    run_dir = pathlib.Path(run_dir)
    history = load_history(run_dir)
    _, metadata = model_file.load_model(model_path)  # raises ModelFileError with its own message
    td = metadata.get("training_data", {})
    net, grid = metadata["network"], metadata["tsdf"]
    card_dir = card_path.parent
    stem = pathlib.Path(model_path).stem
    lines = [f"# Model card: {stem}", "",
             f"_Written by `ros2 run gravgrasp_detector model_card {' '.join(argv or [])}` on "
             f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC. Regenerate it rather than "
             "editing it; only the paragraph under \"What a person saw\" is kept across regenerations._", ""]

    lines += ["## Model", "", "| field | value |", "| --- | --- |"]
    target = td.get("target", "?")
    rows = [
        ("file", f"`{model_path}` ({os.path.getsize(model_path) / 1e6:.2f} MB)"),
        ("sha256", f"`{model_file.file_sha256(model_path)}`"),
        ("created", f"{metadata.get('created_utc', '?')} (torch {metadata.get('torch_version', '?')})"),
        ("architecture", f"`{metadata['architecture']}` (VGN 3D FCN, score / validness / rotation heads)"),
        ("rotation representation", f"`{net.get('rotation_representation')}`"),
        ("target", f"`{target}`" + (" — VGN-style classifier: the score head is untrained, grasps rank by "
                                     f"validness; positive iff the grasp holds {td.get('nominal_mass_kg')} kg × g"
                                     if target == "binary" else " — gravity-rejection score [N], ranked by score")),
        ("training labels", f"`{td.get('subset', '?')}`" + (" (only grasps that settled as precision grasps)"
                                                             if td.get("subset") == "precision-only" else "")),
        ("score scale", f"{_fmt(net.get('score_scale_n'), 4)} N (softplus × scale; median training score)"),
        ("input TSDF", f"{grid['size_m']} m cube, {grid['resolution']}³ voxels of {grid['voxel_size_m'] * 1000:g} mm, "
                       f"truncation {grid['truncation_m'] * 1000:g} mm, convention `{grid['convention']}`"),
        ("epochs, seed", f"{td.get('epochs', '?')}, {td.get('seed', '?')}"),
    ]
    lines += [f"| {k} | {v} |" for k, v in rows] + [""]

    lines += ["## Data", ""]
    data_dir = td.get("data")
    lines.append(f"- scene files: `{data_dir}`; this run used {td.get('scenes_train', '?')} training + "
                 f"{td.get('scenes_val', '?')} validation scenes (split by scene, seed {td.get('seed', '?')}) and "
                 f"{td.get('labels_train', '?')} labelled voxels in its training scenes (after the label subset).")
    tdir = tables_dir_for(data_dir, tables) if data_dir else None
    if recipes:  # scene files are too big to commit; their recipes are not
        objects_out = tdir.parent if tdir is not None and tdir.name == "objects" else tdir  # restore adds objects/
        # recipes packed from scenes of other tables (grown since): the scenes were relabelled
        packed_from = json.loads((pathlib.Path(recipes) / "manifest.json").read_text()).get("objects_dir", "") \
            if (pathlib.Path(recipes) / "manifest.json").is_file() else ""
        relabel = (" --relabel" if objects_out is not None and packed_from
                   and pathlib.Path(packed_from).parent.name != objects_out.resolve().name else "")
        lines.append(f"- the scene files are not committed: `{recipes}` holds their recipes (what the physics "
                     f"decided per scene), and `python -m sim_bridge.datagen recipes restore {recipes} {data_dir} "
                     f"--objects {objects_out or 'TABLES'} --meshes ../shared/meshes/vgn_train{relabel}` rebuilds "
                     "them (~1 CPU-s a scene).")
    if tdir is None:
        lines.append("- grasp tables: not found (no scenes/manifest.json with objects_dir; pass --tables DIR).")
    else:
        text, numbers = data_summary(data_dir, tdir)
        pf = numbers.get("power_fraction")
        lines.append(f"- grasp tables: `{tdir}`: {numbers.get('objects', '?')} objects, {numbers.get('grasps', '?')} "
                     f"held grasps, power fraction {float(pf):.3f}" if pf else f"- grasp tables: `{tdir}`")
        lines += ["", "Dataset summary (`ros2 run sim_bridge data_report` over these tables and all scene files "
                  "of the directory):", "", "```", text, "```"]
    lines.append("")

    lines += ["## Training", ""]
    lines.append(f"- command (as `train` recorded it): `{td.get('command', 'not recorded')}`")
    wall = td.get("train_wall_s", history[-1].get("wall_s"))
    if wall is not None:
        n = history[-1]["epoch"]
        lines.append(f"- training time: {_duration(float(wall))} for {n} epoch{'s' if n != 1 else ''} "
                     f"({float(wall) / max(1, history[-1]['epoch']):.1f} s per epoch, validation included"
                     f"{_epoch_spread(history)})")
    m = td.get("machine")
    if m:
        lines.append(f"- machine: {m.get('cpu', '?')}, {m.get('cores', '?')} logical cores, torch threads "
                     f"{m.get('torch_threads', '?')}, device {m.get('device', '?')}, bf16 autocast "
                     f"{'on' if m.get('bf16') else 'off'}")
    else:
        lines.append("- machine: not recorded by this training run")
    curve, copy = curve_beside_card(run_dir, card_path)
    if curve.is_file():
        lines.append(f"- training curve: {_link(copy, card_dir)} (a copy of {curve})")
    lines.append("")

    lines += ["## Validation metrics", "",
              f"On the {td.get('scenes_val', '?')} validation scenes, whole volumes, no augmentation. The model "
              "file holds the **final** epoch's weights; \"best\" is the best epoch for that metric alone.", "",
              "| metric | final | best (epoch) |", "| --- | --- | --- |"]
    final_epoch = history[-1]["epoch"]
    for key, label, _ in METRICS:
        final, best, epoch = best_and_final(history)[key]
        lines.append(f"| {label} | {_fmt(final)} (epoch {final_epoch}) | {_fmt(best)} ({_fmt(epoch)}) |")
    if target == "binary":
        lines.append("")
        lines.append("Score MAE is meaningless for the binary target (no score loss).")
    lines.append("")

    if calibrations:
        lines += calibration_lines([load_calibration(c) for c in calibrations], list(calibrations))

    lines += ["## Qualitative check (paper Sec. V-A)", "",
              "`make qualitative MODEL=" + str(model_path) + "`: Ø65×200 mm cylinder and 100×80×100 mm box on "
              "the table, one camera at [0.5, 0, 0.5] m (coordinates from the workspace centre on the table "
              "top; task = scene + (0.15, 0.15, 0.05) m). Slices z = 0.15 and 0.08 m (above the table) and "
              "y = 0: input TSDF | score [N] with valid voxels circled and approach directions | validness.", ""]
    pngs = [pathlib.Path(qualitative_dir) / name for name in SLICE_PNGS]
    if any(p.is_file() for p in pngs):
        lines += [f"- {_link(p, card_dir)}" + ("" if p.is_file() else " (missing)") for p in pngs]
    else:
        lines.append(f"_Not run yet: no PNGs in `{qualitative_dir}`._")
    lines += ["", "### What a person saw", "", HUMAN_START, human_notes(card_path), HUMAN_END, ""]
    return "\n".join(lines)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    p = argparse.ArgumentParser(prog="model_card", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="training output directory (model.pt, history.json, training_curve.png)")
    p.add_argument("--model", default=None,
                   help="the model file the card is for, e.g. models/gravgrasp.pt (a copy of RUN/model.pt); "
                        "default RUN/model.pt")
    p.add_argument("--tables", default=None,
                   help="grasp tables directory (default: objects_dir from the scenes' manifest.json)")
    p.add_argument("--qualitative", default=None,
                   help="directory of `make qualitative` PNGs (default out/qualitative/<model stem>)")
    p.add_argument("--out", default=None, help="card path (default: <model dir>/<model stem>.md)")
    p.add_argument("--recipes", default=None,
                   help="committed scene recipes the scene files can be rebuilt from (sim_bridge `datagen recipes`), "
                        "e.g. models/scene_recipes_v3; named on the card so a reader can rebuild the data")
    p.add_argument("--calibration", action="append", default=[], metavar="JSON",
                   help="a score_calibration report (calibration.json) to show, e.g. this model's and the shipped "
                        "one's on the same validation scenes (repeat it: one column each)")
    args = p.parse_args(argv)
    run = pathlib.Path(args.run)
    model = pathlib.Path(args.model) if args.model else run / "model.pt"
    card = pathlib.Path(args.out) if args.out else model.with_suffix(".md")
    qualitative = pathlib.Path(args.qualitative or f"out/qualitative/{model.stem}")
    try:
        run_model = run / "model.pt"
        if model != run_model and run_model.is_file() and model.is_file() \
                and model_file.file_sha256(model) != model_file.file_sha256(run_model):
            raise CardError(f"{model} is not the model of {run} (sha256 differs from {run_model}): copy that "
                            "model.pt there, or give the run directory that produced this model")
        text = render_card(run, model, card, qualitative, args.tables, argv, args.recipes, args.calibration)
    except (CardError, model_file.ModelFileError) as err:
        print(f"model_card: {err}", file=sys.stderr)
        return 2
    curve, copy = curve_beside_card(run, card)
    if curve.is_file():
        atomic_files.save_bytes(copy, curve.read_bytes())
    atomic_files.save_bytes(card, text.encode())
    print(card)
    return 0


if __name__ == "__main__":
    sys.exit(main())
