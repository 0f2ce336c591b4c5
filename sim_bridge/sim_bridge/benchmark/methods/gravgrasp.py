"""The project's own detectors: a model file (gravgrasp_detector.perception.model_file)
run by the project's detection as the detect node serves it, under the protocol's
detection settings (and its clear_hand: hand_clearing.py). The volume is the one the
model was trained on (its metadata). Score models rank by the gravity-rejection score
[N] with the protocol's min_score_n; binary models by validness (their success
probability).

A study's variant (sim_bridge.studies.detection_levers) is a grasp-plan function built
from the same pieces: `load` a model file, `detection_options` changed, and `make_detect`
with its own rank_key, restriction of the candidates or score model."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from gravgrasp_detector.perception.detection import (DetectionOptions, network_outputs, rotations_at,
                                                     select_grasps)
from gravgrasp_detector.perception.model_file import check_volume, has_score, load_model, ranking, training_target
from gravgrasp_detector.perception.tsdf import TSDFVolume

from .hand_clearing import clear_hand
from .method import Detector, Method


def load(path):
    """(model, metadata, TSDFVolume it was trained on) of the model file at `path`."""
    model, metadata = load_model(path)
    volume = TSDFVolume(size_m=metadata["tsdf"]["size_m"], resolution=metadata["tsdf"]["resolution"])
    check_volume(metadata, volume.resolution, volume.voxel_size_m, volume.truncation_m)
    return model, metadata, volume


def detection_options(metadata, protocol, **changes) -> DetectionOptions:
    """The detect node's options for this model under the protocol (`changes`: a variant's)."""
    options = DetectionOptions(validness_threshold=protocol.validness_threshold, min_score_n=protocol.min_score_n,
                               max_grasps=protocol.max_grasps, rank_by=ranking(metadata),
                               has_score=has_score(metadata))
    return dataclasses.replace(options, **changes)


def make_detect(model, protocol, options, rank_key=None, restrict=None, score_model=None):
    """tsdf tuple -> ranked grasps: detection with `options` and, when the protocol says
    so, its clear_hand. A variant's changes: rank_key(score_n, validness) -> the (R, R, R)
    key that ranks the candidates; restrict(grid, candidate, poses_at, voxel_size_m) ->
    the candidates it keeps (before ranking); score_model: another GraspNet whose score
    [N] stands for `model`'s (`model`'s validness and rotations still place the grasps)."""

    @torch.inference_mode()
    def detect(tsdf):
        grid, voxel_size_m, origin = tsdf
        if not np.any(grid):
            return []
        grid = torch.as_tensor(np.asarray(grid, dtype=np.float32))
        half, score_n, validness = network_outputs(model, grid, options.precision)
        if score_model is not None:
            _, score_n, _ = network_outputs(score_model, grid, options.precision)

        def from_candidates(grid, candidate, ranked, poses_at):
            if restrict is not None:
                candidate = candidate & restrict(grid, candidate, poses_at, voxel_size_m)
            if protocol.clear_hand:
                return clear_hand(grid, candidate, ranked, poses_at, voxel_size_m, options.nms_radius_voxels)
            return ranked(candidate)
        return select_grasps(grid, score_n if options.has_score else None, validness, rotations_at(model, half),
                             model.rotation_representation, voxel_size_m, origin, options,
                             None if rank_key is None else rank_key(score_n, validness), from_candidates)
    return detect


def make_detector(path, protocol) -> Detector:
    """The model file at `path` as the benchmark's Detector."""
    model, metadata, volume = load(path)
    return Detector(make_detect(model, protocol, detection_options(metadata, protocol)), volume,
                    training_target(metadata))


def model_method(name: str, file: str = "", summary: str = "") -> Method:
    """A method that runs a model file on the paper's hand, the 2F-85 (`file` under the
    models directory; "" for one given only by --model NAME=PATH)."""
    return Method(name, "2f85", make_detector, file, summary=summary)
