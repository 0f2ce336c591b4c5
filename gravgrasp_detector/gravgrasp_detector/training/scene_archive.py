"""One compact file holding the training part of many scene files, to move a dataset
to a training machine (a GPU box) that has no simulator to regenerate it.

    python -m gravgrasp_detector.training.scene_archive pack out/scenes_v2 scenes.npz.xz
    python -m gravgrasp_detector.training.scene_archive unpack scenes.npz.xz out/scenes_v2

A scene file (sim_bridge's scene stage) is ~57 KB; the archive keeps what training
reads (`scenes.load_scene`): the TSDF as float16 (at most 2.5e-4 from the
float32 grid on TSDF values in [0, 1]), the labels and the explicit negatives, and drops
the rest (cameras, object poses, provenance), ~18 KB a scene after xz. Unpacking writes
one uncompressed file per scene (~260 KB) under its original name, so the train/validation split by file
name (`scenes.split_scenes`) is the same on both machines.
"""
from __future__ import annotations

import argparse
import io
import lzma
import pathlib
import sys

import numpy as np

from .. import atomic_files
from .scenes import DataError

# per-label arrays, concatenated over scenes
LABEL_KEYS = ("label_index", "label_score", "label_e_x", "label_e_z", "label_mode")


def pack(scene_dir, archive_path) -> int:
    """Pack every scene file (*.npz, recursively) under scene_dir into archive_path
    (written atomically). Returns the number of scenes."""
    files = sorted(pathlib.Path(scene_dir).rglob("*.npz"))
    if not files:
        raise DataError(f"no scene files (*.npz) under {scene_dir}")
    names, grids, label_counts, negative_counts = [], [], [], []
    labels = {k: [] for k in LABEL_KEYS}
    negatives, mode_names = [], None
    for f in files:
        try:
            with np.load(f) as z:
                if "label_mode" not in z or "negative_index" not in z:
                    raise DataError(f"{f} has no label_mode/negative_index; regenerate it with "
                                    "'ros2 run sim_bridge datagen scenes'")
                names.append(str(f.relative_to(scene_dir)))
                grids.append(z["tsdf"].astype(np.float16))
                label_counts.append(len(z["label_score"]))
                for k in LABEL_KEYS:
                    labels[k].append(z[k])
                negatives.append(z["negative_index"].reshape(-1, 3))
                negative_counts.append(len(negatives[-1]))
                scene_modes = [str(n) for n in z["mode_names"]]
        except (OSError, KeyError, ValueError) as err:
            raise DataError(f"scene file {f} is unreadable ({err}); regenerate it") from None
        if mode_names is None:
            mode_names = scene_modes
        elif scene_modes != mode_names:
            raise DataError(f"{f} names its grasp modes {scene_modes}, other scenes {mode_names}")
    arrays = {"names": np.array(names), "tsdf": np.stack(grids),
              "label_count": np.array(label_counts, np.int64),
              "negative_count": np.array(negative_counts, np.int64),
              "negative_index": np.concatenate(negatives).astype(np.uint8),
              "mode_names": np.array(mode_names)}
    arrays.update({k: np.concatenate(v) for k, v in labels.items()})
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_files.save_bytes(archive_path, lzma.compress(buf.getvalue(), preset=6))
    return len(names)


def unpack(archive_path, scene_dir) -> int:
    """Write one scene file per archived scene under scene_dir (skipping those already
    there). Returns the number of scenes in the archive."""
    try:
        with lzma.open(archive_path) as f:
            z = np.load(io.BytesIO(f.read()))
            arrays = {k: z[k] for k in z.files}
    except (OSError, lzma.LZMAError, ValueError) as err:
        raise DataError(f"{archive_path} is not a scene archive ({err}); make it with "
                        "'python -m gravgrasp_detector.training.scene_archive pack'") from None
    label_end = np.cumsum(arrays["label_count"])
    negative_end = np.cumsum(arrays["negative_count"])
    for i, name in enumerate(arrays["names"]):
        path = pathlib.Path(scene_dir) / str(name)
        if path.exists():
            continue
        l0, l1 = label_end[i] - arrays["label_count"][i], label_end[i]
        n0, n1 = negative_end[i] - arrays["negative_count"][i], negative_end[i]
        buf = io.BytesIO()  # uncompressed: a working copy, written and read fast
        np.savez(buf, tsdf=arrays["tsdf"][i].astype(np.float32), negative_index=arrays["negative_index"][n0:n1],
                 mode_names=arrays["mode_names"], **{k: arrays[k][l0:l1] for k in LABEL_KEYS})
        atomic_files.save_bytes(path, buf.getvalue())
    return len(arrays["names"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Pack scene files into one archive, or unpack one.")
    sub = p.add_subparsers(dest="command", required=True)
    a = sub.add_parser("pack", help="scene directory -> archive")
    a.add_argument("scenes"), a.add_argument("archive")
    b = sub.add_parser("unpack", help="archive -> scene directory")
    b.add_argument("archive"), b.add_argument("scenes")
    args = p.parse_args(argv)
    try:
        if args.command == "pack":
            n = pack(args.scenes, args.archive)
            size_mb = pathlib.Path(args.archive).stat().st_size / 1e6
            print(f"packed {n} scenes into {args.archive} ({size_mb:.1f} MB)")
        else:
            n = unpack(args.archive, args.scenes)
            print(f"unpacked {n} scenes into {args.scenes}")
    except DataError as err:
        print(f"scene_archive: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
