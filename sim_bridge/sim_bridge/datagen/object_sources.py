"""Where a grasp table's object comes from, so that any process can rebuild it.

An `ObjectSource` names a mesh file (URDF/OBJ/STL) or one of a seeded set of
procedural objects; `load()` builds its `ObjectSpec`, refusing what Drake cannot
simulate. `mesh_sources` / `procedural_sources` list the sources of a stage run,
`read_name_list` reads a file of object names (e.g. the held-out meshes), and
`object_from_table` rebuilds the object a table was simulated with, checked against
the table's `shape_sha256` fingerprint.
"""

import functools
import hashlib
import pathlib
from dataclasses import dataclass

import numpy as np
import trimesh

from ..physics.objects import ObjectError, load_mesh_object, random_procedural_objects


@dataclass(frozen=True)
class ObjectSource:
    """How to (re)build an object in any process: a mesh file or a procedural index."""

    name: str
    kind: str            # "mesh" | "procedural"
    path: str = ""       # mesh: URDF/OBJ path
    proc_seed: int = 0   # procedural: random_procedural_objects(proc_count, proc_seed)[proc_index]
    proc_count: int = 0
    proc_index: int = 0
    density_kg_m3: float = 0.0  # mesh: for bare OBJ/STL files (URDFs carry their mass)

    def load(self):
        if self.kind == "mesh":
            p = pathlib.Path(self.path)
            if p.suffix.lower() in (".obj", ".stl"):
                m = trimesh.load(str(p), force="mesh")
                if not m.is_watertight:
                    raise ObjectError(f"{p.name}: mesh is not watertight; repair it (or give a URDF "
                                      "with a convex-decomposed collision mesh)")
            spec = load_mesh_object(self.path, density_kg_m3=self.density_kg_m3 or None)
        else:
            spec = _procedural(self.proc_count, self.proc_seed)[self.proc_index]
        _check_parts(spec)
        return spec

    @property
    def source(self):
        if self.kind == "mesh":
            return pathlib.Path(self.path).name
        return f"{self.proc_seed}:{self.proc_count}:{self.proc_index}"


def _check_parts(spec):
    """Drake aborts the whole process (not an exception) on a primitive with a
    non-positive size, which would take a worker pool down: refuse it here."""
    for k, part in enumerate(spec.parts):
        if part.kind != "convex" and not (np.all(np.isfinite(part.size)) and min(part.size) > 0):
            raise ObjectError(f"{spec.name}: collision part {k} ({part.kind}) has size {tuple(part.size)}; "
                              "every size must be positive")


@functools.lru_cache(maxsize=1)
def _procedural(count, seed):
    # a worker rebuilds object i of the same set many times: build the set once
    return random_procedural_objects(count, seed)


def mesh_sources(mesh_dir, density_kg_m3=0.0):
    """URDFs of a directory (VGN layout), else its OBJ files, sorted by name."""
    d = pathlib.Path(mesh_dir)
    if not d.is_dir():
        raise ObjectError(f"mesh directory {d} does not exist")
    files = sorted(d.glob("*.urdf")) or sorted(p for p in d.glob("*.obj") if not p.stem.endswith("_collision"))
    return [ObjectSource(p.stem, "mesh", path=str(p.resolve()), density_kg_m3=density_kg_m3) for p in files]


def read_name_list(path):
    """Object names of a list file (one per line, '#' comments), e.g. the held-out meshes."""
    p = pathlib.Path(path)
    if not p.is_file():
        raise ObjectError(f"name list {p} does not exist")
    return {line.split("#")[0].strip() for line in p.read_text().splitlines()} - {""}


def procedural_sources(count, seed):
    return [ObjectSource(f"proc{seed}_{i:05d}", "procedural", proc_seed=seed, proc_count=count, proc_index=i)
            for i in range(count)]


def object_from_table(table, mesh_dirs=()):
    """The ObjectSpec a grasp table was made for; ObjectError if it cannot be found or
    is no longer the same shape (then the table must be regenerated). The same object of
    the same file is built once per process (treat the spec as read-only)."""
    expected = str(table["shape_sha256"]) if "shape_sha256" in table else None
    return _checked_object(source_from_table(table, mesh_dirs), expected)


@functools.lru_cache(maxsize=512)
def _checked_object(source, expected_sha256):
    # a scene worker rebuilds each object ~100 times over 5,000 scenes; loading a mesh
    # and fingerprinting it cost about as much as labelling the scene
    spec = source.load()
    if expected_sha256 is not None and shape_sha256(spec) != expected_sha256:
        raise ObjectError(f"{source.name}: the object is not the one its grasp table was simulated with "
                          "(objects.py or the mesh changed); regenerate its table")
    return spec


def source_from_table(table, mesh_dirs=()):
    """ObjectSource of a loaded grasp table; mesh files are looked up in mesh_dirs."""
    name, kind, source = str(table["name"]), str(table["source_kind"]), str(table["source"])
    if kind == "procedural":
        seed, count, index = (int(v) for v in source.split(":"))
        return ObjectSource(name, kind, proc_seed=seed, proc_count=count, proc_index=index)
    for d in mesh_dirs:
        p = pathlib.Path(d) / source
        if p.is_file():
            return ObjectSource(name, kind, path=str(p.resolve()))
    raise ObjectError(f"{name}: mesh {source} not found in {', '.join(map(str, mesh_dirs)) or 'no --meshes dir'}")


def shape_sha256(spec):
    """Fingerprint of an object's collision shape and mass: a table is only valid for
    the object it was simulated with (objects.py or a mesh file may change later)."""
    m = spec.collision_mesh()
    h = hashlib.sha256()
    for a in (np.round(np.asarray(m.vertices, float), 6), np.asarray(m.faces, np.int64),
              np.round([spec.mass_kg], 9), np.round(np.asarray(spec.com_m, float), 6)):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()
