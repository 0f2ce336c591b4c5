"""The project's own detectors: a model file (gravgrasp_detector.perception.model_file)
run by the project's detection, as the detect node serves it. The volume is the one the
model was trained on (its metadata). Score models rank by the gravity-rejection score
[N] with the protocol's min_score_n; binary models by validness (their success
probability); a ranking variant overrides that (`rank_by`, e.g. "expected_score"), a
selection variant the validness below which a grasp is not taken (`validness_floor`) or
VGN's mask on the candidates (`free_space_mask`: DetectionOptions'). A method told the
payload (`told_payload`) ranks by validness, either among the grasps predicted to hold it
with the stack's safety factor (`payload_rule` "floor": detection.payload_min_score_n) or
with those the executed grasps' calibration says hold it first ("preferred":
detection.held_payload_score_n). A method with a `score_file` ranks its model's grasps by
another model's score (detection.detect_grasps' score_model: Binary places, Ours ranks)."""

from __future__ import annotations

import functools
import pathlib

import numpy as np

from gravgrasp_detector.perception.detection import (DetectionOptions, detect_grasps, held_payload_score_n,
                                                     payload_min_score_n)
from gravgrasp_detector.perception.model_file import (check_volume, has_score, load_model, load_score_model, ranking,
                                                     training_target)
from gravgrasp_detector.perception.tsdf import TSDFVolume

from .method import Detector, Method


PAYLOAD_RULES = ("floor", "preferred")


def make_detect(model, metadata, protocol, rank_by=None, validness_floor=0.0, free_space_mask="off",
                payload_kg=None, payload_rule="floor", score_model=None):
    """tsdf tuple -> ranked grasps, under the protocol's detection settings (and at least
    `validness_floor` of validness, VGN's mask where `free_space_mask` says, and with a
    `payload_kg`, by validness: `payload_rule` "floor" among the grasps scored >= 1.5 x
    its weight, "preferred" those the executed grasps' calibration says hold it first;
    with a `score_model` (model, metadata), ranked by its score)."""
    min_score_n, prefer_score_n = protocol.min_score_n, 0.0
    scorer = None
    if score_model is not None:
        scorer, score_metadata = score_model
        if not has_score(score_metadata):
            raise ValueError("the score model has no gravity-rejection score (trained with --target binary)")
        metadata = score_metadata  # its score ranks: model_file.ranking says "score"
    if payload_rule not in PAYLOAD_RULES:
        raise ValueError(f"payload_rule {payload_rule!r}: use one of {PAYLOAD_RULES}")
    if payload_kg is not None:
        if not has_score(metadata):
            raise ValueError("a payload selects by the gravity-rejection score, and this model has none "
                             "(trained with --target binary)")
        rank_by = "validness"
        if payload_rule == "floor":
            min_score_n = max(min_score_n, payload_min_score_n(payload_kg))
        else:
            prefer_score_n = held_payload_score_n(payload_kg)
    options = DetectionOptions(validness_threshold=max(protocol.validness_threshold, validness_floor),
                               min_score_n=min_score_n,
                               max_grasps=protocol.max_grasps, rank_by=rank_by or ranking(metadata),
                               has_score=has_score(metadata), clear_hand=protocol.clear_hand,
                               free_space_mask=free_space_mask, prefer_score_n=prefer_score_n)

    def detect(tsdf):
        grid, voxel_size_m, origin = tsdf
        if not np.any(grid):
            return []
        return detect_grasps(model, grid, voxel_size_m, origin, options, score_model=scorer)
    return detect


def make_detector(path, protocol, rank_by=None, validness_floor=0.0, free_space_mask="off",
                  payload_kg=None, payload_rule="floor", score_file="") -> Detector:
    """The model file at `path` as the benchmark's Detector (`score_file`: the model file
    beside it whose score ranks its grasps)."""
    model, metadata = load_model(path)
    volume = TSDFVolume(size_m=metadata["tsdf"]["size_m"], resolution=metadata["tsdf"]["resolution"])
    check_volume(metadata, volume.resolution, volume.voxel_size_m, volume.truncation_m)
    score_model = load_score_model(pathlib.Path(path).parent / score_file, metadata) if score_file else None
    detect = make_detect(model, metadata, protocol, rank_by, validness_floor, free_space_mask, payload_kg,
                         payload_rule, score_model)
    return Detector(detect, volume, training_target(score_model[1] if score_model else metadata))


def model_method(name: str, file: str = "", summary: str = "", rank_by=None, file_of: str = "",
                 validness_floor: float = 0.0, free_space_mask: str = "off", told_payload: bool = False,
                 payload_rule: str = "floor", score_file: str = "") -> Method:
    """A method that runs a model file on the paper's hand, the 2F-85 (`file` under the
    models directory; "" for one given only by --model NAME=PATH; `score_file` beside it:
    the model whose score ranks its grasps)."""
    make = functools.partial(make_detector, rank_by=rank_by, validness_floor=validness_floor,
                             free_space_mask=free_space_mask, payload_rule=payload_rule, score_file=score_file)
    return Method(name, "2f85", make, file, summary=summary, file_of=file_of, told_payload=told_payload,
                  companions=(score_file,) if score_file else ())
