"""What the cell's fixed depth camera sees: its pose and intrinsics (`CameraSettings`),
and the visual meshes of the table, the objects and the hand (`SceneMeshes`), posed as
the plant is now and ray cast by Open3D (physics.depth_rendering), so the hand shows up
when it is in view, as on a real cell."""

from __future__ import annotations

import numpy as np
import trimesh
from pydrake.geometry import Box, Capsule, Convex, Cylinder, Mesh, Sphere

from gravgrasp_detector.perception.tsdf import CameraIntrinsics

from ..physics.depth_rendering import DepthRenderer, look_at
from ..physics.scenes import TABLE_HEIGHT_M, VOLUME_SIZE_M
from .config import CameraSettings


def camera_pose(camera: CameraSettings) -> np.ndarray:
    """T_task_camera (4x4, optical frame)."""
    return look_at(camera.position_m, camera.target_m)


def camera_intrinsics(camera: CameraSettings) -> CameraIntrinsics:
    """What TSDFVolume.integrate takes."""
    c = camera
    return CameraIntrinsics(c.width, c.height, c.focal_px, c.focal_px, (c.width - 1) / 2, (c.height - 1) / 2)


def render_depth(camera: CameraSettings, posed_meshes) -> tuple:
    """(depth float32 HxW [m], 0 = no return; CameraIntrinsics; T_task_camera 4x4) of
    `posed_meshes` ((trimesh, X_task_mesh) pairs)."""
    T = camera_pose(camera)
    k = camera_intrinsics(camera)
    return DepthRenderer(posed_meshes).render(k, T, camera.max_depth_m), k, T


class SceneMeshes:
    """The visual meshes of one world (`diagram.WorldDiagram`, its objects' ObjectSpecs
    by name), loaded at the first frame."""

    def __init__(self, model, specs: dict):
        self._model, self._specs = model, specs
        self._meshes = None

    def posed(self, plant_context, names) -> list:
        """(trimesh, X_task_mesh) for the table, the objects `names` and every hand link."""
        plant = self._model.plant
        if self._meshes is None:
            self._meshes = self._load()
        cache = self._meshes
        out = [(cache["table"], np.eye(4))]
        bodies = dict(zip(self._specs, self._model.object_bodies))
        for n in names:
            out.append((cache["objects"][n], plant.EvalBodyPoseInWorld(plant_context, bodies[n]).GetAsMatrix4()))
        for body, mesh, X_BG in cache["hand"]:
            out.append((mesh, plant.EvalBodyPoseInWorld(plant_context, body).GetAsMatrix4() @ X_BG))
        return out

    def _load(self):
        table = trimesh.creation.box((1.0, 1.0, 0.05))
        table.apply_translation([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M - 0.025])
        objects = {}
        for n, spec in self._specs.items():
            objects[n] = (trimesh.load(spec.visual_mesh_path, force="mesh") if spec.visual_mesh_path
                          else spec.collision_mesh())
        plant, inspector = self._model.plant, self._model.scene_graph.model_inspector()
        hand = []
        for bi in plant.GetBodyIndices(self._model.hand.model_instance):
            body = plant.get_body(bi)
            for gid in plant.GetVisualGeometriesForBody(body):
                mesh = _shape_mesh(inspector.GetShape(gid))
                if mesh is not None:
                    hand.append((body, mesh, inspector.GetPoseInFrame(gid).GetAsMatrix4()))
        return {"table": table, "objects": objects, "hand": hand}


def _shape_mesh(shape):
    """trimesh of a Drake shape in its geometry frame (None for shapes a camera would not
    see or that we do not draw)."""
    if isinstance(shape, Box):
        return trimesh.creation.box((shape.width(), shape.depth(), shape.height()))
    if isinstance(shape, Cylinder):
        return trimesh.creation.cylinder(radius=shape.radius(), height=shape.length(), sections=32)
    if isinstance(shape, Sphere):
        return trimesh.creation.icosphere(subdivisions=3, radius=shape.radius())
    if isinstance(shape, Capsule):
        return trimesh.creation.capsule(height=shape.length(), radius=shape.radius())
    if isinstance(shape, (Mesh, Convex)):
        src = shape.source()
        if not src.is_path():
            return None
        m = trimesh.load(str(src.path()), force="mesh")
        m.apply_scale(shape.scale3())
        return m.convex_hull if isinstance(shape, Convex) else m
    return None
