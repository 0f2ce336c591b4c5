"""Graspable objects: procedural primitives and mesh objects (URDF or OBJ) for Drake.

An `ObjectSpec` is a rigid body described by its mass properties and a list of convex
collision `Part`s in the object frame. Convex pieces keep contact fast and let every
piece be a compliant hydroelastic body (a non-convex `.obj` would act as its hull).

pydrake (and `contact`, which loads it) is imported inside the two methods that build
Drake geometry, so that objects (shapes, masses, meshes) can be described and sampled
without loading Drake, which costs a process seconds and ~70 MB.
"""

from __future__ import annotations

import pathlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np
import trimesh

PRIMITIVE_KINDS = ("box", "cylinder", "sphere", "capsule", "box_with_handle")
MIN_PART_VOLUME_M3 = 1e-9  # 1 mm³: below this a piece is degenerate (flat or a line)


class ObjectError(ValueError):
    """An object cannot be simulated; the message says what is wrong and what to do."""


@dataclass
class Part:
    """One convex collision piece. kind: box (size = full x,y,z), cylinder (radius,
    length along z), sphere (radius,), capsule (radius, length of the cylindrical
    section), convex (vertices (n,3) in the part frame)."""

    kind: str
    size: tuple = ()
    X_O_P: np.ndarray = field(default_factory=lambda: np.eye(4))
    vertices: np.ndarray | None = None

    def trimesh(self) -> trimesh.Trimesh:
        if self.kind == "box":
            m = trimesh.creation.box(extents=self.size)
        elif self.kind == "cylinder":
            m = trimesh.creation.cylinder(radius=self.size[0], height=self.size[1], sections=64)
        elif self.kind == "sphere":
            m = trimesh.creation.icosphere(subdivisions=4, radius=self.size[0])
        elif self.kind == "capsule":
            m = trimesh.creation.capsule(height=self.size[1], radius=self.size[0], count=[32, 32])
        elif self.kind == "convex":
            m = trimesh.Trimesh(self.vertices).convex_hull
        else:
            raise ObjectError(f"unknown part kind {self.kind!r}")
        m.apply_transform(self.X_O_P)
        return m

    def drake_shape(self):
        from pydrake.geometry import Box, Capsule, Convex, Cylinder, Sphere  # lazy: pydrake (see the module doc)

        if self.kind == "box":
            return Box(*self.size)
        if self.kind == "cylinder":
            return Cylinder(self.size[0], self.size[1])
        if self.kind == "sphere":
            return Sphere(self.size[0])
        if self.kind == "capsule":
            return Capsule(self.size[0], self.size[1])
        return Convex(np.asarray(self.vertices, float).T.copy(), "convex_part")

    def resolution_hint_m(self) -> float:
        """Hydroelastic tessellation size for curved primitives (~20 segments round)."""
        if self.kind in ("cylinder", "sphere", "capsule"):
            return float(np.clip(0.3 * self.size[0], 0.003, 0.02))
        return 0.01  # unused by Drake for boxes and convex pieces


@dataclass
class ObjectSpec:
    """A rigid object. Frame O is the object frame of the parts (not necessarily at
    the COM); `com_m` and `inertia_kg_m2` (about the COM, axes of O) for `mass_kg`."""

    name: str
    mass_kg: float
    com_m: np.ndarray
    inertia_kg_m2: np.ndarray
    parts: list
    visual_mesh_path: str | None = None  # rendering only; None: draw the parts

    def collision_mesh(self) -> trimesh.Trimesh:
        """All collision pieces, concatenated, in the object frame."""
        return trimesh.util.concatenate([p.trimesh() for p in self.parts])

    def with_mass(self, mass_kg: float) -> "ObjectSpec":
        """Same shape and mass distribution, scaled to `mass_kg`."""
        _check_mass(mass_kg, self.name)
        s = mass_kg / self.mass_kg
        return ObjectSpec(self.name, mass_kg, self.com_m.copy(), self.inertia_kg_m2 * s,
                          self.parts, self.visual_mesh_path)

    def add_to_plant(self, plant, name=None, mass_kg=None, proximity_properties=None):
        """Add as a free rigid body (before Finalize) with its own model instance.

        Returns the RigidBody; its body frame is the object frame O. Every part gets a
        copy of `proximity_properties` (default: the paper's contact parameters,
        `grasp_simulation.proximity_properties(SimSettings())`) with a per-part
        hydroelastic resolution hint.
        """
        # lazy: pydrake (see the module doc)
        from pydrake.geometry import Mesh, ProximityProperties
        from pydrake.math import RigidTransform
        from pydrake.multibody.tree import RotationalInertia, SpatialInertia

        from .contact import SimSettings
        from .contact import proximity_properties as paper_properties

        if proximity_properties is None:
            proximity_properties = paper_properties(SimSettings())
        spec = self if mass_kg is None else self.with_mass(mass_kg)
        name = name or spec.name
        mi = plant.AddModelInstance(name)
        I = spec.inertia_kg_m2
        I_com = RotationalInertia(I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2])
        M = SpatialInertia.MakeFromCentralInertia(spec.mass_kg, spec.com_m, I_com)
        body = plant.AddRigidBody(name, mi, M)
        for k, part in enumerate(spec.parts):
            X = RigidTransform(part.X_O_P)
            shape = part.drake_shape()
            props = ProximityProperties(proximity_properties)
            if props.HasProperty("hydroelastic", "resolution_hint"):
                props.UpdateProperty("hydroelastic", "resolution_hint", part.resolution_hint_m())
            plant.RegisterCollisionGeometry(body, X, shape, f"{name}_c{k}", props)
            if spec.visual_mesh_path is None:
                plant.RegisterVisualGeometry(body, X, shape, f"{name}_v{k}", [0.85, 0.55, 0.2, 1.0])
        if spec.visual_mesh_path is not None:
            plant.RegisterVisualGeometry(body, RigidTransform(), Mesh(spec.visual_mesh_path),
                                         f"{name}_visual", [0.85, 0.55, 0.2, 1.0])
        return body


def _check_mass(mass_kg, what):
    if mass_kg is None or not np.isfinite(mass_kg) or mass_kg <= 0:
        raise ObjectError(f"{what}: mass {mass_kg!r} kg is not positive; give a mass in kg "
                          "(or a density) > 0")


def _mass_properties(mesh: trimesh.Trimesh, mass_kg, what):
    if mesh.volume <= MIN_PART_VOLUME_M3:
        raise ObjectError(f"{what}: volume {mesh.volume:.3g} m³ is ~zero (flat or broken "
                          "mesh); give a closed mesh with volume")
    mesh = mesh.copy()
    mesh.density = mass_kg / mesh.volume
    return np.asarray(mesh.center_mass, float), np.asarray(mesh.moment_inertia, float)


def _from_parts(name, parts, mass_kg, density_kg_m3, visual_mesh_path=None) -> ObjectSpec:
    # Drake aborts the process (no exception) on a non-positive primitive size.
    for k, part in enumerate(parts):
        if part.kind != "convex" and not (np.all(np.isfinite(part.size)) and min(part.size) > 0):
            raise ObjectError(f"{name}: collision part {k} ({part.kind}) has size {tuple(part.size)}; "
                              "every size must be positive")
    mesh = trimesh.util.concatenate([p.trimesh() for p in parts])
    if mass_kg is None:
        if density_kg_m3 is None:
            raise ObjectError(f"{name}: give mass_kg or density_kg_m3")
        mass_kg = density_kg_m3 * mesh.volume
    _check_mass(mass_kg, name)
    com, inertia = _mass_properties(mesh, mass_kg, name)
    return ObjectSpec(name, float(mass_kg), com, inertia, parts, visual_mesh_path)


def procedural_object(kind: str, dims_m, mass_kg=None, density_kg_m3=None, name=None) -> ObjectSpec:
    """A primitive in its own frame (centred; cylinders and capsules along z).

    dims_m: box (x, y, z); cylinder (diameter, length); sphere (diameter,);
    capsule (diameter, total length); box_with_handle (x, y, z of the box; a U-handle
    min(20 mm, z/4) thick sticks out >= 40 mm along +x, spanning 60% of z).
    """
    dims = tuple(float(d) for d in np.atleast_1d(dims_m))
    need = {"box": 3, "cylinder": 2, "sphere": 1, "capsule": 2, "box_with_handle": 3}
    if kind not in need:
        raise ObjectError(f"unknown object kind {kind!r}; use one of {', '.join(PRIMITIVE_KINDS)}")
    if len(dims) != need[kind] or min(dims) <= 0 or not np.all(np.isfinite(dims)):
        raise ObjectError(f"{kind}: dims {dims} must be {need[kind]} positive lengths in metres")
    name = name or f"{kind}_" + "x".join(f"{d * 1000:.0f}" for d in dims) + "mm"
    if kind == "box":
        parts = [Part("box", dims)]
    elif kind == "cylinder":
        parts = [Part("cylinder", (dims[0] / 2, dims[1]))]
    elif kind == "sphere":
        parts = [Part("sphere", (dims[0] / 2,))]
    elif kind == "capsule":
        if dims[1] < dims[0]:
            raise ObjectError(f"capsule: total length {dims[1]} shorter than its diameter {dims[0]}")
        parts = [Part("capsule", (dims[0] / 2, dims[1] - dims[0]))]
    else:
        x, y, z = dims
        # handle bar thickness shrinks with short boxes so every piece stays positive
        span = 0.6 * z
        t, reach = min(0.02, 0.25 * z), max(0.04, 2 * min(0.02, 0.25 * z))

        def at(p):
            X = np.eye(4)
            X[:3, 3] = p
            return X

        parts = [
            Part("box", (x, y, z)),
            Part("box", (reach, t, t), at((x / 2 + reach / 2, 0, span / 2 - t / 2))),
            Part("box", (reach, t, t), at((x / 2 + reach / 2, 0, -span / 2 + t / 2))),
            Part("box", (t, t, span - 2 * t), at((x / 2 + reach - t / 2, 0, 0))),
        ]
    return _from_parts(name, parts, mass_kg, density_kg_m3)


def parse_object_arg(text: str, mass_kg=None, density_kg_m3=None) -> ObjectSpec:
    """'cylinder:0.065x0.2' -> procedural object; anything else is a URDF/OBJ path."""
    if ":" in text and text.split(":")[0] in PRIMITIVE_KINDS:
        kind, dims = text.split(":", 1)
        try:
            d = [float(v) for v in dims.split("x")]
        except ValueError:
            raise ObjectError(f"{text!r}: dims must look like 0.065x0.2 (metres)") from None
        return procedural_object(kind, d, mass_kg, density_kg_m3)
    return load_mesh_object(text, mass_kg, density_kg_m3)


def _load_mesh(path: pathlib.Path, what: str, split: bool):
    if not path.is_file():
        raise ObjectError(f"{what}: mesh file {path} not found")
    try:
        m = trimesh.load(str(path), force="mesh", process=True)
    except Exception as e:  # trimesh raises many types for broken files
        raise ObjectError(f"{what}: cannot read {path}: {e}; re-export it as OBJ") from e
    if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
        raise ObjectError(f"{what}: {path} holds no triangles; re-export it as a triangle mesh")
    return m.split(only_watertight=False) if split else [m]


def load_mesh_object(path, mass_kg=None, density_kg_m3=None) -> ObjectSpec:
    """Load a URDF (mass + visual mesh + convex-decomposed collision OBJ, as VGN's
    objects) or a bare OBJ/STL (needs mass_kg or density_kg_m3).

    Collision pieces are the connected components of the collision mesh, each used as
    its convex hull. Mass properties come from the visual mesh when it is watertight,
    else from the collision pieces (URDF inertias are ignored: VGN's are placeholders).
    """
    path = pathlib.Path(path)
    what = path.name
    if not path.is_file():
        raise ObjectError(f"{what}: file {path} not found")
    visual = None
    if path.suffix.lower() == ".urdf":
        try:
            root = ET.parse(path).getroot()
        except ET.ParseError as e:
            raise ObjectError(f"{what}: not valid XML ({e}); fix the URDF") from e
        links = root.findall("link")
        if len(links) != 1:
            raise ObjectError(f"{what}: has {len(links)} links; objects must be one rigid link")
        link = links[0]
        m_el = link.find("inertial/mass")
        if mass_kg is None and density_kg_m3 is None:
            if m_el is None:
                raise ObjectError(f"{what}: no <inertial><mass>; add one or pass mass_kg")
            try:
                mass_kg = float(m_el.get("value"))
            except (TypeError, ValueError):
                raise ObjectError(f"{what}: <mass value> is not a number; fix the URDF") from None

        def mesh_of(tag):
            el = link.find(f"{tag}/geometry/mesh")
            if el is None:
                return None, 1.0
            scale = np.array([float(s) for s in (el.get("scale") or "1 1 1").split()])
            if not np.allclose(scale, scale[0]):
                raise ObjectError(f"{what}: non-uniform mesh scale {scale} is not supported")
            return path.parent / el.get("filename").replace("package://", ""), float(scale[0])

        col_path, col_scale = mesh_of("collision")
        vis_path, vis_scale = mesh_of("visual")
        if col_path is None:
            raise ObjectError(f"{what}: no <collision><geometry><mesh>; add a convex-decomposed OBJ")
        pieces = _load_mesh(col_path, what, split=True)
        for p in pieces:
            p.apply_scale(col_scale)
        if vis_path is not None and vis_path.is_file() and vis_scale == 1.0 and vis_path.suffix.lower() == ".obj":
            visual = _load_mesh(vis_path, what, split=False)[0]
    else:
        pieces = _load_mesh(path, what, split=True)
        visual = _load_mesh(path, what, split=False)[0]
    parts = []
    for p in pieces:
        try:
            with np.errstate(invalid="ignore", divide="ignore"):  # flat pieces: 0 volume
                hull = p.convex_hull
                volume = hull.volume
        except Exception:  # qhull rejects degenerate (flat, collinear) point sets
            continue
        if volume > MIN_PART_VOLUME_M3:
            parts.append(Part("convex", vertices=np.asarray(hull.vertices)))
    if not parts:
        raise ObjectError(f"{what}: every collision piece has ~zero volume (flat or broken "
                          "mesh); give a closed collision mesh")
    hull_mesh = trimesh.util.concatenate([p.trimesh() for p in parts])
    source = visual if (visual is not None and visual.is_watertight and visual.volume > MIN_PART_VOLUME_M3) else hull_mesh
    if mass_kg is None:
        if density_kg_m3 is None:
            raise ObjectError(f"{what}: give mass_kg or density_kg_m3 (bare meshes carry no mass)")
        if source is visual and not visual.is_watertight:
            raise ObjectError(f"{what}: mesh is not watertight, so its volume (and a mass from "
                              "density) is undefined; repair it or pass mass_kg")
        mass_kg = density_kg_m3 * source.volume
    _check_mass(mass_kg, what)
    com, inertia = _mass_properties(source, mass_kg, what)
    vis_path_str = str(vis_path) if (path.suffix.lower() == ".urdf" and visual is not None) else (
        str(path) if path.suffix.lower() == ".obj" else None)
    return ObjectSpec(path.stem, float(mass_kg), com, inertia, parts, vis_path_str)


def random_procedural_objects(n: int, seed: int) -> list:
    """`n` household-sized primitives (densities 150–900 kg/m³, 0.03–1.5 kg); most fit
    the 85 mm stroke across at least one direction, some do not (on purpose)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        kind = rng.choice(PRIMITIVE_KINDS, p=[0.3, 0.3, 0.15, 0.15, 0.1])
        if kind in ("box", "box_with_handle"):
            dims = [rng.uniform(0.025, 0.09), rng.uniform(0.03, 0.12), rng.uniform(0.04, 0.2)]
            rng.shuffle(dims)
        elif kind == "cylinder":
            dims = [rng.uniform(0.02, 0.095), rng.uniform(0.04, 0.22)]
        elif kind == "sphere":
            dims = [rng.uniform(0.03, 0.095)]
        else:
            d = rng.uniform(0.02, 0.07)
            dims = [d, d + rng.uniform(0.03, 0.15)]
        spec = procedural_object(str(kind), dims, density_kg_m3=rng.uniform(150, 900),
                                 name=f"obj{i:03d}_{kind}")
        out.append(spec.with_mass(float(np.clip(spec.mass_kg, 0.03, 1.5))))
    return out
