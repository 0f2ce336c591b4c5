"""The project's own detectors: a model file (gravgrasp_detector.perception.model_file)
run by the project's detection, as the detect node serves it. The volume is the one the
model was trained on (its metadata). Score models rank by the gravity-rejection score
[N] with the protocol's min_score_n; binary models by validness (their success
probability); a ranking variant overrides that (`rank_by`, e.g. "expected_score"), a
selection variant the validness below which a grasp is not taken (`validness_floor`) or
VGN's mask on the candidates (`free_space_mask`: DetectionOptions')."""

from __future__ import annotations

import functools

import numpy as np

from gravgrasp_detector.perception.detection import DetectionOptions, detect_grasps
from gravgrasp_detector.perception.model_file import check_volume, has_score, load_model, ranking, training_target
from gravgrasp_detector.perception.tsdf import TSDFVolume

from .method import Detector, Method


def make_detect(model, metadata, protocol, rank_by=None, validness_floor=0.0, free_space_mask="off"):
    """tsdf tuple -> ranked grasps, under the protocol's detection settings (and at least
    `validness_floor` of validness, and VGN's mask where `free_space_mask` says)."""
    options = DetectionOptions(validness_threshold=max(protocol.validness_threshold, validness_floor),
                               min_score_n=protocol.min_score_n,
                               max_grasps=protocol.max_grasps, rank_by=rank_by or ranking(metadata),
                               has_score=has_score(metadata), clear_hand=protocol.clear_hand,
                               free_space_mask=free_space_mask)

    def detect(tsdf):
        grid, voxel_size_m, origin = tsdf
        if not np.any(grid):
            return []
        return detect_grasps(model, grid, voxel_size_m, origin, options)
    return detect


def make_detector(path, protocol, rank_by=None, validness_floor=0.0, free_space_mask="off") -> Detector:
    """The model file at `path` as the benchmark's Detector."""
    model, metadata = load_model(path)
    volume = TSDFVolume(size_m=metadata["tsdf"]["size_m"], resolution=metadata["tsdf"]["resolution"])
    check_volume(metadata, volume.resolution, volume.voxel_size_m, volume.truncation_m)
    return Detector(make_detect(model, metadata, protocol, rank_by, validness_floor, free_space_mask), volume,
                    training_target(metadata))


def model_method(name: str, file: str = "", summary: str = "", rank_by=None, file_of: str = "",
                 validness_floor: float = 0.0, free_space_mask: str = "off") -> Method:
    """A method that runs a model file on the paper's hand, the 2F-85 (`file` under the
    models directory; "" for one given only by --model NAME=PATH)."""
    make = functools.partial(make_detector, rank_by=rank_by, validness_floor=validness_floor,
                             free_space_mask=free_space_mask)
    return Method(name, "2f85", make, file, summary=summary, file_of=file_of)
