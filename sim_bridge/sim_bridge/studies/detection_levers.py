"""The detection levers the lever studies measured, as benchmark methods: each a grasp-plan
function over the shipped detection's steps (benchmark.methods.gravgrasp), registered here
(not in the benchmark's registry, which holds the shipped models and the paper's
baselines). None became a default; what each measured: sim_bridge/doc/levers.md and
payload-selection.md.

    python -m sim_bridge.studies.detection_levers --methods ours_sure,binary --out DIR ...
    python -m sim_bridge.studies.detection_levers TOOL ARGS...   # TOOL: one of TOOLS

runs the benchmark (the same options as `ros2 run sim_bridge benchmark`), or an analysis
tool that takes method names, with these methods known; importing this module registers
them for any other code.

| method | lever |
| --- | --- |
| ours_expected | Ours ranked by validness x score instead of the score among valid voxels |
| ours_sure, ours_precision_sure | Ours' (Ours-Precision's) score trusted only at validness >= 0.9 |
| ours_masked | Ours among the grasps VGN's mask keeps where VGN's TCP would sit |
| ours_mass | told the mass: by validness among grasps scored >= 1.5 x the weight |
| ours_told | told the mass: by validness, the grasps scored >= what executed grasps needed first |
| binary_scored | Binary's grasps of validness >= 0.9, ranked by Ours' score |
"""

from __future__ import annotations

import importlib
import json
import math
import os
import pathlib
import sys

import numpy as np
import torch

from gravgrasp_detector.perception.detection import G_MPS2, payload_min_score_n
from gravgrasp_detector.perception.model_file import ModelFileError, has_score, load_model, training_target

from ..benchmark.methods import Detector, Method, gravgrasp, register
from ..benchmark.methods.vgn import FINGER_BASE_Z_M, free_space_band

SURE_VALIDNESS = 0.9  # Binary's picks' median validness was 0.97, Ours' failed picks' 0.62-0.82
EXECUTED_HOLD_FILE = pathlib.Path("models/calibration/gravgrasp_executed_hold.json")


# -- the levers ----------------------------------------------------------------------


def expected_score(score_n, validness):
    """rank_key: validness x score (a voxel that barely passes the threshold with a high
    score, which the score head was never trained at, no longer outranks a sure one)."""
    return score_n * validness


def preferring(min_score_n):
    """rank_key: by validness, the grasps scored >= min_score_n first (validness in [0, 1])."""
    return lambda score_n, validness: validness + (score_n >= min_score_n).float()


def at_vgn_tcp(grid, candidate, poses_at, voxel_size_m):
    """restrict: the candidates VGN's mask (vgn.free_space_band) keeps at the voxel itself.
    VGN's TCP is the Panda's finger base and this one the pinch point between the pads,
    inside what a grasp holds, so it keeps only grasps that pinch in front of a surface."""
    return free_space_band(grid)


def at_vgn_finger_base(grid, candidate, poses_at, voxel_size_m):
    """restrict: the candidates VGN's mask (vgn.free_space_band) keeps at the point
    FINGER_BASE_Z_M along each candidate's approach, where VGN's TCP would sit (every
    candidate's rotation, as VGN masks before its non-maximum suppression; about 10x the
    detection's time)."""
    band = free_space_band(grid)
    index = candidate.nonzero()
    keeps = torch.zeros_like(candidate)
    if len(index):
        poses = poses_at(index)
        points = poses[:, :3, 3] + FINGER_BASE_Z_M * poses[:, :3, 2]
        ijk = np.floor(points / voxel_size_m).astype(int)
        inside = np.all((ijk >= 0) & (ijk < np.array(band.shape)), axis=1)
        at_base = np.zeros(len(ijk), bool)
        at_base[inside] = band.numpy()[tuple(ijk[inside].T)]
        keeps[tuple(index[torch.as_tensor(at_base)].T)] = True
    return keeps


def held_payload_score_n(mass_kg, calibration_file=None):
    """The predicted score [N] that executed grasps needed to hold `mass_kg` 4 times in 5
    (the study-fitted line in EXECUTED_HOLD_FILE, under GRAVGRASP_ROOT)."""
    if not (math.isfinite(mass_kg) and mass_kg >= 0):
        raise ValueError(f"payload {mass_kg} kg: give a mass >= 0 kg")
    path = pathlib.Path(calibration_file or pathlib.Path(os.environ.get("GRAVGRASP_ROOT", ".")) / EXECUTED_HOLD_FILE)
    line = json.loads(path.read_text())
    return line["offset_n"] + line["n_per_weight_n"] * mass_kg * G_MPS2


def load_score_model(path, placing_metadata):
    """-> (model, metadata) of a score model that ranks another model's grasps (binary_scored):
    one with a gravity-rejection score, on the same TSDF as the model that places them
    (`placing_metadata`). Raises ModelFileError."""
    model, metadata = load_model(path)
    if not has_score(metadata):
        raise ModelFileError(f"score model {os.path.abspath(os.fspath(path))} was trained with --target binary: "
                             "it has no gravity-rejection score to rank by; give a score model (models/gravgrasp.pt)")
    scoring, placing = metadata["tsdf"], placing_metadata["tsdf"]

    def same(key):
        if key in ("voxel_size_m", "truncation_m"):
            return abs(scoring[key] - placing[key]) <= 1e-9
        return scoring.get(key) == placing.get(key)

    differ = [f"{k} {scoring.get(k)} (placing model: {placing.get(k)})"
              for k in ("resolution", "voxel_size_m", "truncation_m", "convention") if not same(k)]
    if differ:
        raise ModelFileError(f"score model {os.path.abspath(os.fspath(path))} reads another TSDF than the model "
                             f"that places the grasps: {', '.join(differ)}; give one trained on the same volume")
    return model, metadata


# VGN's mask as a restriction of the candidates, by where it is tested (first_view_picks)
VGN_MASKS = {"tcp": at_vgn_tcp, "finger_base": at_vgn_finger_base}


# -- as benchmark methods ------------------------------------------------------------


def lever_detector(path, protocol, rank_key=None, validness_floor=0.0, restrict=None, payload_kg=None,
                   payload_rule=None, score_file=""):
    """The model file at `path` under one lever (see the module doc) as a methods.Detector."""
    model, metadata, volume = gravgrasp.load(path)
    score_model = None
    if score_file:
        score_model, metadata = load_score_model(pathlib.Path(path).parent / score_file, metadata)
    changes = {"validness_threshold": max(protocol.validness_threshold, validness_floor)}
    if payload_kg is not None:
        if not has_score(metadata):
            raise ValueError("a payload selects by the gravity-rejection score, and this model has none")
        changes["rank_by"] = "validness"
        if payload_rule == "floor":
            changes["min_score_n"] = max(protocol.min_score_n, payload_min_score_n(payload_kg))
        else:
            rank_key = preferring(held_payload_score_n(payload_kg))
    options = gravgrasp.detection_options(metadata, protocol, **changes)
    detect = gravgrasp.make_detect(model, protocol, options, rank_key, restrict, score_model)
    return Detector(detect, volume, training_target(metadata))


def lever(name, file, summary, file_of, told_payload=False, score_file="", **how) -> Method:
    def make(path, protocol, payload_kg=None):
        return lever_detector(path, protocol, payload_kg=payload_kg, score_file=score_file, **how)
    return Method(name, "2f85", make, file, summary=summary, file_of=file_of, told_payload=told_payload,
                  companions=(score_file,) if score_file else ())


LEVERS = (
    lever("ours_expected", "gravgrasp.pt", "Ours ranked by validness x score", "ours", rank_key=expected_score),
    lever("ours_sure", "gravgrasp.pt", "Ours ranked by score among grasps of validness >= 0.9", "ours",
          validness_floor=SURE_VALIDNESS),
    lever("ours_precision_sure", "gravgrasp_precision_only.pt",
          "Ours-Precision ranked by score among grasps of validness >= 0.9", "ours_precision",
          validness_floor=SURE_VALIDNESS),
    lever("ours_masked", "gravgrasp.pt", "Ours among grasps VGN's mask keeps at its finger base", "ours",
          restrict=at_vgn_finger_base),
    lever("ours_mass", "gravgrasp.pt", "Ours told the mass: by validness among grasps scored >= 1.5 x the weight",
          "ours", told_payload=True, payload_rule="floor"),
    lever("ours_told", "gravgrasp.pt", "Ours told the mass: by validness, grasps scored >= what executed grasps "
          "needed to hold it first", "ours", told_payload=True, payload_rule="preferred"),
    lever("binary_scored", "gravgrasp_binary.pt", "Binary's grasps of validness >= 0.9, ranked by Ours' score",
          "binary", validness_floor=SURE_VALIDNESS, score_file="gravgrasp.pt"),
)
for _method in LEVERS:
    register(_method, "sim_bridge.studies.detection_levers")  # not __name__: "__main__" under python -m


# the tools that look methods up by name, run with the levers known
TOOLS = {"benchmark": "sim_bridge.benchmark.clutter_benchmark", "paired_run": "sim_bridge.analysis.paired_run",
         "replay": "sim_bridge.analysis.replay", "round_profile": "sim_bridge.analysis.round_profile"}


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    tool = argv.pop(0) if argv and argv[0] in TOOLS else "benchmark"
    return importlib.import_module(TOOLS[tool]).main(argv)


if __name__ == "__main__":
    sys.exit(main())
