"""What the per-object stages that add to grasp tables share (perturb, wrap, rescore):
one worker task per object, each answering ("ok", counts) or ("error", message), the
counts summed into the stage's summary; an error is reported and retried on the next
run while the other objects go on. Plus the folder of rows appended to the tables."""

import pathlib

from gravgrasp_detector import atomic_files

from ..parallel import make_executor, run_tasks


def run_per_object(fn, tasks, kept, counts, desc, workers=None, progress=True) -> dict:
    """Run `fn(task)` for every task; `counts` names the numbers an "ok" answer carries.
    Returns {done, kept, <counts>..., errors}."""
    summary = dict(done=0, kept=kept, **dict.fromkeys(counts, 0), errors=[])

    def on_result(task, result):
        status, payload = result
        if status == "ok":
            summary["done"] += 1
            for k, v in zip(counts, payload):
                summary[k] += v
        else:
            summary["errors"].append(payload)

    if tasks:
        with make_executor(workers) as ex:
            run_tasks(ex, fn, tasks, on_result, desc=desc, progress=progress)
    return summary


def appended_rows_dir(objects_out, directory) -> pathlib.Path:
    """`<objects_out>/objects/<directory>`, made and cleared of stale temporaries; the
    tables' folder (objects/), or FileNotFoundError if `objects_out` holds none."""
    objects_dir = pathlib.Path(objects_out) / "objects"
    if not objects_dir.is_dir():
        raise FileNotFoundError(f"{objects_out} holds no grasp tables (no objects/ directory): "
                                "give the --out of `datagen objects`")
    (objects_dir / directory).mkdir(exist_ok=True)
    atomic_files.remove_stale_temporaries(objects_dir / directory)
    return objects_dir
