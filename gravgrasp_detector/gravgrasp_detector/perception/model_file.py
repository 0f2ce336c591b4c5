"""Model files: network weights + the metadata needed to use them correctly.

A model file is a `torch.save`d dict, loaded with `weights_only=True` (no pickled
code runs on load):
    format: "gravgrasp-model", format_version: 1,
    metadata: {architecture, network (GraspNet constructor args: rotation
               representation, score scale, resolution), tsdf {size_m, resolution,
               voxel_size_m, truncation_m, convention}, training_data (free-form
               summary: dataset, scenes, epochs, command ...), created_utc,
               torch_version},
    state_dict: GraspNet weights.
A volume whose size, resolution, truncation or value convention differs from the
metadata is rejected by `check_volume` with a message that says what to change.

Paths in training_data are relative to the project the model was trained in (the
working directory of `train`), or left out: a model file travels to other machines,
and the trainer's absolute paths say nothing there but where someone's home was.
Files written before this rule (the shipped models carry `cwd` and an absolute `data`)
are made portable when loaded (`portable_training_data`), so nothing downstream sees
those paths.
"""

import datetime
import hashlib
import os
import posixpath

import torch

from .. import atomic_files
from . import networks, tsdf

FORMAT = "gravgrasp-model"
FORMAT_VERSION = 1


class ModelFileError(RuntimeError):
    """A model file that cannot be used; the message says why and what to do."""


def tsdf_metadata(volume):
    """The `tsdf` metadata block describing a tsdf.TSDFVolume."""
    return tsdf.volume_metadata(volume.size_m, volume.resolution, volume.truncation_voxels)


def portable_training_data(training_data, root=None):
    """A copy of a training summary with every absolute path made relative to `root`
    (default: the `cwd` it recorded) or, outside it, dropped (None); `cwd` itself goes."""
    data = dict(training_data or {})
    root = root or data.get("cwd")
    data.pop("cwd", None)

    def portable(value):
        if isinstance(value, dict):
            return {k: portable(v) for k, v in value.items()}
        if isinstance(value, list):
            return [portable(v) for v in value]
        if not isinstance(value, str):
            return value
        if posixpath.isabs(value):
            if root and posixpath.isabs(root):
                rel = posixpath.relpath(posixpath.normpath(value), posixpath.normpath(root))
                if not rel.startswith(".."):
                    return rel
            return None
        if root and posixpath.isabs(root):  # paths inside a recorded command line
            value = value.replace(posixpath.normpath(root) + "/", "")
        return value

    return portable(data)


def save_model(path, model, tsdf_volume_or_metadata, training_data=None):
    """Write `model` (networks.GraspNet) atomically to `path` and return its metadata."""
    tsdf_meta = (
        dict(tsdf_volume_or_metadata)
        if isinstance(tsdf_volume_or_metadata, dict)
        else tsdf_metadata(tsdf_volume_or_metadata)
    )
    if tsdf_meta["resolution"] != model.resolution:
        raise ValueError(
            f"network resolution {model.resolution} != TSDF resolution {tsdf_meta['resolution']}"
        )
    metadata = {
        "architecture": networks.ARCHITECTURE,
        "network": model.config(),
        "tsdf": tsdf_meta,
        "training_data": portable_training_data(training_data, os.getcwd()),
        "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "torch_version": str(torch.__version__),
    }
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    payload = {"format": FORMAT, "format_version": FORMAT_VERSION, "metadata": metadata, "state_dict": state}
    atomic_files.save_torch(path, payload)
    return metadata


def training_target(metadata: dict) -> str:
    """'gravity-score' or 'binary' (training/loop.py records it in training_data.target)."""
    return str((metadata.get("training_data") or {}).get("target", "gravity-score"))


def has_score(metadata: dict) -> bool:
    """Whether the model predicts a gravity-rejection score in N (detection.DetectionOptions.
    has_score): not one trained with `--target binary`, whose score head is untrained."""
    return training_target(metadata) != "binary"


def ranking(metadata: dict) -> str:
    """How detection ranks this model's grasps (detection.DetectionOptions.rank_by):
    "validness" for a model trained with `--target binary` (its validness is its success
    probability), else "score" (the paper's rule)."""
    return "score" if has_score(metadata) else "validness"


def file_sha256(path) -> str:
    """sha256 of a file (a model's identity in cards and benchmark rounds)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def load_model(path):
    """-> (networks.GraspNet in eval mode, metadata). Raises ModelFileError."""
    path = os.path.abspath(os.fspath(path))
    if not os.path.isfile(path):
        raise ModelFileError(
            f"model file {path} does not exist: train a model (models/ has the model "
            "cards) or point model_path at an existing .pt file"
        )
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for a damaged file
        raise ModelFileError(
            f"model file {path} cannot be read ({type(e).__name__}: {str(e).splitlines()[0][:120]}): "
            "the file is corrupt or not a gravgrasp model; re-copy or re-export it"
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ModelFileError(
            f"model file {path} is not a gravgrasp model file (no format={FORMAT!r}): "
            "export it with gravgrasp_detector.perception.model_file.save_model"
        )
    if payload.get("format_version") != FORMAT_VERSION:
        raise ModelFileError(
            f"model file {path} has format_version {payload.get('format_version')}, this "
            f"gravgrasp_detector reads version {FORMAT_VERSION}: update the package or re-export"
        )
    metadata = payload.get("metadata")
    if not isinstance(metadata, dict) or not {"architecture", "network", "tsdf"} <= set(metadata):
        raise ModelFileError(
            f"model file {path} lacks metadata (architecture, network, tsdf): re-export it with save_model"
        )
    metadata = dict(metadata, training_data=portable_training_data(metadata.get("training_data")))
    if metadata["architecture"] != networks.ARCHITECTURE:
        raise ModelFileError(
            f"model file {path} is architecture {metadata['architecture']!r}, this package "
            f"runs {networks.ARCHITECTURE!r}: use a matching gravgrasp_detector version"
        )
    try:
        model = networks.GraspNet(**metadata["network"])
        model.load_state_dict(payload["state_dict"])
    except (TypeError, ValueError, RuntimeError, KeyError) as e:
        first = str(e).strip().splitlines()[0][:160]
        raise ModelFileError(
            f"model file {path}: weights do not match its metadata ({first}): the file is "
            "corrupt or was edited; re-export it"
        ) from None
    return model.eval(), metadata


def check_volume(metadata, resolution, voxel_size_m, truncation_m, convention=tsdf.TSDF_CONVENTION):
    """Raise ModelFileError unless a volume of this geometry is what the model was trained on."""
    expected = metadata["tsdf"]
    problems = []
    if int(resolution) != int(expected["resolution"]):
        problems.append(f"resolution {resolution} (model: {expected['resolution']})")
    if abs(voxel_size_m - expected["voxel_size_m"]) > 1e-6:
        problems.append(f"voxel size {voxel_size_m:.6g} m (model: {expected['voxel_size_m']:.6g} m)")
    if abs(truncation_m - expected["truncation_m"]) > 1e-6:
        problems.append(f"truncation {truncation_m:.6g} m (model: {expected['truncation_m']:.6g} m)")
    if convention != expected["convention"]:
        problems.append(f"value convention {convention!r} (model: {expected['convention']!r})")
    if problems:
        raise ModelFileError(
            "TSDF does not match the model: " + ", ".join(problems)
            + f"; set the tsdf node to size_m={expected.get('size_m')}, "
            f"resolution={expected['resolution']}, truncation {expected['truncation_m']:.6g} m, "
            "or use a model trained for this volume"
        )
