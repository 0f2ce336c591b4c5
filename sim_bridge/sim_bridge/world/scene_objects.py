"""The objects of a scene (`SceneConfig`): given, or drawn (procedural primitives or
URDF/OBJ files) and arranged on the table, each with a unique name."""

from __future__ import annotations

import pathlib

import numpy as np

from ..physics.objects import load_mesh_object, random_procedural_objects
from ..physics.scenes import SceneSettings, arrange
from .config import BARE_MESH_DENSITY_KG_M3, SceneConfig


def draw_scene(cfg: SceneConfig) -> tuple:
    """([(unique name, ObjectSpec)], [X_task_object 4x4]) of the scene's objects."""
    if cfg.objects:
        specs = [spec for spec, _ in cfg.objects]
        poses = [np.asarray(X, float) for _, X in cfg.objects]
    else:
        if cfg.mesh_dir:
            d = pathlib.Path(cfg.mesh_dir)
            entries = sorted(d.iterdir()) if d.is_dir() else []
            # URDFs (VGN's: mass + meshes) when there are any; their OBJs are parts of them
            files = [p for p in entries if p.suffix.lower() == ".urdf"] or [
                p for p in entries if p.suffix.lower() == ".obj"]
            if not files:
                raise ValueError(f"mesh_dir {cfg.mesh_dir!r}: no .urdf or .obj files there")
            pick = np.random.default_rng(cfg.seed).choice(len(files), min(cfg.n_objects, len(files)), replace=False)
            # bare OBJs carry no mass: object_mass_kg, else a household density
            density = None if cfg.object_mass_kg > 0 or files[0].suffix.lower() == ".urdf" else BARE_MESH_DENSITY_KG_M3
            specs = [load_mesh_object(files[i], mass_kg=cfg.object_mass_kg or None, density_kg_m3=density)
                     for i in pick]
        else:
            specs = random_procedural_objects(cfg.n_objects, cfg.seed)
    if cfg.object_mass_kg > 0:
        specs = [s.with_mass(cfg.object_mass_kg) for s in specs]
    if not cfg.objects:
        keep, poses = arrange(specs, cfg.arrangement, np.random.default_rng(cfg.seed), SceneSettings())
        specs = [specs[i] for i in keep]
    named, seen = [], set()
    for i, spec in enumerate(specs):
        name = spec.name if spec.name not in seen else f"{spec.name}_{i}"
        seen.add(name)
        named.append((name, spec))
    return named, poses
