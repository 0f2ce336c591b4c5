"""What a benchmark method is: a detector (the TSDF of a view -> grasps, best first) made
from one file, and the hand that executes its grasps. The registry is methods.METHODS."""

from __future__ import annotations

import dataclasses
import os
import pathlib
from typing import Callable

from ...physics import baseline_files

MODELS, BASELINES = "models", "baselines"  # where a method's file lives


class MethodFileMissing(FileNotFoundError):
    """A method's file is not there (the message says which and where to get it)."""


@dataclasses.dataclass(frozen=True)
class Detector:
    """A method made ready for one cell: `detect((grid, voxel_size_m, origin))` -> grasps
    best first (each with `pose` T_task_tcp of the method's hand, `score_n` in N or NaN for
    a method without a score, `validness`, and `rank_key`: what it was ranked by),
    reading views integrated into `volume` (a TSDFVolume of its own)."""
    detect: Callable
    volume: object
    # what it predicts, for the round record and the report: a model file's training
    # target ("gravity-score": a score in N), "binary" (validness only: score_n NaN)
    target: str


@dataclasses.dataclass(frozen=True)
class Method:
    """One entry of methods.METHODS. `make(path, protocol)` -> Detector, `path` being the
    method's file (the project's model file, a baseline's weights): its sha256 names the
    detector in the round records, so a rerun redoes the rounds of a changed file."""
    name: str
    hand: str  # physics.hands: "2f85" (the paper's) or "panda" (the baselines')
    make: Callable
    file: str  # under the models directory, or under the baselines directory (`where`)
    where: str = MODELS
    summary: str = ""
    # A variant runs another method's file ("ours_expected": Ours' model ranked otherwise):
    # that method's --model NAME=PATH moves it along.
    file_of: str = ""
    # Other files `make` reads from beside its file (the same directory; VN-EdgeGraspNet's
    # four checkpoints): `locate` checks them too. Only `file`'s sha256 names the detector.
    companions: tuple = ()
    # Told each round's object mass: `make(path, protocol, payload_kg=mass)` (a detector
    # that selects by a known payload; the others are not told).
    told_payload: bool = False

    def __post_init__(self):
        if self.where not in (MODELS, BASELINES):
            raise ValueError(f"method {self.name!r}: where={self.where!r}, use {MODELS!r} or {BASELINES!r}")

    def default_path(self, models_dir: str | os.PathLike = "models", baselines_dir=None) -> pathlib.Path:
        """Where its file is by default (not checked)."""
        if self.where == MODELS:
            return pathlib.Path(models_dir) / self.file
        return baseline_files.baselines_dir(baselines_dir) / self.file

    def locate(self, models_dir: str | os.PathLike = "models", baselines_dir=None, override=None) -> pathlib.Path:
        """Its file (`override`: a --model path), resolved; MethodFileMissing saying where
        to get it otherwise."""
        if override:
            path = pathlib.Path(override)
        elif self.where == BASELINES:
            try:
                path = baseline_files.baseline_file(self.file, baselines_dir)
            except FileNotFoundError as e:
                raise MethodFileMissing(str(e)) from None
        else:
            path = self.default_path(models_dir)
        if not path.is_file():
            raise MethodFileMissing(f"model file {path} not found")
        missing = [str(path.parent / pathlib.PurePosixPath(c).name) for c in self.companions
                   if not (path.parent / pathlib.PurePosixPath(c).name).is_file()]
        if missing:
            source = (baseline_files.SOURCES.get(pathlib.PurePosixPath(self.file).parts[0], "where its file came from")
                      if self.where == BASELINES else "models/, which ships it, or pass --model with a directory that has it")
            raise MethodFileMissing(f"{', '.join(missing)} not found beside {path.name}: get "
                                    f"{'them' if len(missing) > 1 else 'it'} from {source}")
        return path.resolve()
