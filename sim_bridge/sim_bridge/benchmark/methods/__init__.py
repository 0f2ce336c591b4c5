"""The benchmark's methods, by name: the shipped models and the paper's baselines. A
method is a detector (the TSDF of a view -> grasps, best first) and the hand that executes
them (`method.Method`); the round, its SR/CR rules, the protocol and the reports are the
same for every method.

Adding a method: a module here whose `make_detector(path, protocol)` returns a
`method.Detector`, and one `Method` entry in METHODS (its hand, and its file: under the
models directory, or under the baselines directory for other people's weights, which
the project never copies into its tree: physics.baseline_files). A study's variant
registers itself from its own module (`register`, e.g. sim_bridge.studies.detection_levers);
a round's worker imports that module again (PROVIDERS) before it looks the method up."""

from __future__ import annotations

import importlib

from . import gravgrasp, vgn, vgn_2f85, vn_edge
from .method import BASELINES, Detector, Method, MethodFileMissing

__all__ = ["METHODS", "PROVIDERS", "Detector", "Method", "MethodFileMissing", "method_named", "method_of",
           "register"]

METHODS = {m.name: m for m in (
    # the project's models (the lead's training runs write these files into models/)
    gravgrasp.model_method("ours", "gravgrasp.pt", "Ours: the gravity-rejection score [N]"),
    gravgrasp.model_method("ours_precision", "gravgrasp_precision_only.pt", "Ours trained on precision grasps only"),
    gravgrasp.model_method("binary", "gravgrasp_binary.pt", "the same network trained on binary success"),
    gravgrasp.model_method("ours_ey_ez", "gravgrasp_ey_ez.pt", "rotation ablation: e_y-e_z columns"),
    gravgrasp.model_method("ours_quat", "gravgrasp_quat.pt", "rotation ablation: a quaternion"),
    # the baselines, with their published weights, on the hand they were made for
    Method("vgn", "panda", vgn.make_detector, vgn.MODEL_FILE, BASELINES,
           "VGN (Breyer et al. 2020), published weights, Panda hand"),
    # VGN's detector on the project's hand (its grasps moved to the 2F-85's TCP, the finger
    # tips kept where they were: vgn_2f85.py): the detector apart from the hand
    Method("vgn_2f85", "2f85", vgn_2f85.make_detector, vgn.MODEL_FILE, BASELINES,
           "VGN's published weights, its grasps executed by the 2F-85"),
    Method("vn_edge", "panda", vn_edge.make_detector, vn_edge.MODEL_FILE, BASELINES,
           "VN-EdgeGraspNet (Huang et al. 2023), published weights, Panda hand",
           companions=vn_edge.COMPANION_FILES),
)}
# run by default (clutter_benchmark --methods): the project's models; baselines when named
DEFAULT_METHODS = ("ours", "ours_precision", "binary", "ours_ey_ez", "ours_quat")
# a study's method -> the module that registered it (a spawned worker imports it again)
PROVIDERS: dict = {}


def register(method: Method, provider: str) -> None:
    """Make a study's `method` known by name; `provider`: its module's import name."""
    if method.name in METHODS and PROVIDERS.get(method.name) != provider:
        raise ValueError(f"method {method.name!r} is registered already")
    METHODS[method.name] = method
    PROVIDERS[method.name] = provider


def method_named(name: str, provider: str = "") -> Method:
    """The registered method `name` (`provider`: the module that registers it, imported
    first when given); ValueError naming the known ones otherwise."""
    if provider and name not in METHODS:
        importlib.import_module(provider)
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown method {name!r}: use one of {', '.join(METHODS)} "
                         "(or --model NAME=PATH for another model file)") from None


def method_of(name: str, model_path: str = "", provider: str = "") -> Method:
    """The method a round of `name` runs: the registered one, or, for a name given only by
    --model NAME=PATH (`model_path`), that model file on the 2F-85."""
    if provider and name not in METHODS:
        importlib.import_module(provider)
    if name not in METHODS and model_path:
        return gravgrasp.model_method(name)
    return method_named(name)
