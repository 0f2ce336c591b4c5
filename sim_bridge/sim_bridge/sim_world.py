"""The simulated robot cell behind the sim bridge: a Drake world with gravity, a table, a
scene of objects and the underactuated 2F-85 carried by an arm stand-in. No rclpy.

    world = SimWorld(SceneConfig(seed=3, n_objects=4), WorldSettings())
    world.move_tcp(X_task_tcp, speed_mps=0.1)        # (success, message)
    plant = world.finger_plant()                       # robotiq FingerPlant backed by physics
    depth, intrinsics, T_task_camera = world.render_depth()
    world.object_states()                              # ground truth

Frames: everything is in the task frame (z up, origin at a corner of the 0.30 m cube,
table top at z = scenes.TABLE_HEIGHT_M); the Drake world frame *is* the task frame.

Arm stand-in (as in the paper's simulated benchmark, a free-floating hand on Cartesian
paths): the hand is a floating body whose pose and velocity are *set* before every time
step from a straight-line, minimum-jerk TCP reference (translation along a line,
rotation along the geodesic), like a MuJoCo mocap body. This is an infinitely stiff
position-controlled arm: nothing sags under a heavy object, and there are no stand-in
gains to tune against SAP (a stiff explicit PD on the floating base needs gains near the
explicit-stability limit at dt = 2 ms and still sagged degrees under a 1.5 kg object in a
side grasp). Gravity is off for the hand only (the arm carries it). The fingers stay fully
dynamic and the contacts are SAP's. The net contact force on the hand links (what a wrist
force/torque sensor reads) stops a motion when it exceeds `max_contact_force_n`.

Fingers: `FingerServoSystem` (a LeafSystem) is the 2F-85's motor: a position servo on the
driver joint whose reference moves at the commanded speed and whose torque is clipped at
the value that squeezes the commanded force (grasp_simulation's calibration). Blocked by
an object, the reference runs on to the target and the torque saturates: a force-limited
grip, as the real gripper does. Width is reported from the driver angle through the
free-closing calibration (`DRIVER_ANGLE_RAD` -> `PAD_GAP_M`), as the real gripper reports
its motor position, not the pad gap.

Depth: Open3D ray casting of the posed visual meshes (table, objects, hand), so the hand
shows up when it is in view, as on a real cell.

Thread safety: every public method takes one lock, so a `RealTimeRunner` thread can
step the world while other threads command it and read from it.
"""

from __future__ import annotations

import gc
import math
import threading
import time
import weakref
from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from . import hand_model
from .grasp_simulation import SimSettings, driver_torque_nm, proximity_properties
from .scenes import TABLE_HEIGHT_M, TABLE_FRICTION, VOLUME_SIZE_M, SceneSettings, arrange

# Free closing of the Menagerie 2F-85 in Drake (slow torque, no object): driver angle ->
# gap between the pad faces. The pads touch each other at 0.775 rad (gap 1.1 mm).
DRIVER_ANGLE_RAD = np.array([0.0, 0.057, 0.101, 0.158, 0.2, 0.258, 0.312, 0.352, 0.404,
                             0.455, 0.505, 0.555, 0.603, 0.651, 0.709, 0.754, 0.775])
PAD_GAP_M = 1e-3 * np.array([85.4, 80.14, 75.99, 70.37, 66.11, 60.07, 54.28, 49.93, 44.13,
                             38.34, 32.59, 26.89, 21.26, 15.7, 8.88, 3.53, 1.1])
STROKE_M = hand_model.MAX_STROKE_M
PARKING_SHELF_M = (5.0, 5.0, -5.0)  # top surface of the shelf removed objects go to (task frame)
# d(gap)/d(angle), mean over the stroke: converts the commanded finger speed (m/s of
# opening, as the 2F-85's rSP) to a driver rate.
GAP_PER_DRIVER_RAD_M = (PAD_GAP_M[0] - PAD_GAP_M[-1]) / DRIVER_ANGLE_RAD[-1]
FINGER_LINKS = frozenset(hand_model.LEFT_LINKS + hand_model.RIGHT_LINKS
                         + ("left_silicone_pad", "right_silicone_pad"))

# The hand's floating body weighs this much in the simulation. Its state is reset every
# step, but within a step SAP moves it under the contact forces: at its real 0.8 kg a held
# 0.3 kg object dragged it down 12 um per step, which the reset turned into a 6 mm/s slip
# of the object in the grasp. At 1000 kg the same load gives 6 um/s.
STAND_IN_MASS_KG = 1000.0
DRIVER_DAMPING_NMS_PER_RAD = 0.3  # the finger servo's damping (implicit in SAP)

BARE_MESH_DENSITY_KG_M3 = 500.0  # mesh_dir of bare OBJs without object_mass_kg

# Hand pointing down: TCP z (approach) = -task z, closing axis y = -task y.
R_TOP_DOWN = np.diag([1.0, -1.0, -1.0])


def width_from_driver_angle(angle_rad: float) -> float:
    """Finger opening [m] the 2F-85 reports at a driver angle (clipped to 0..stroke)."""
    w = float(np.interp(angle_rad, DRIVER_ANGLE_RAD, PAD_GAP_M))
    return min(max(w, 0.0), STROKE_M)


def driver_angle_for_width(width_m: float) -> float:
    """Driver angle [rad] for an opening [m]; 0 m gives the closed limit (0.8 rad), beyond
    where the pads meet, so 'close' squeezes whatever is between them."""
    if width_m <= PAD_GAP_M[-1]:
        return hand_model.DRIVER_CLOSED_RAD
    return float(np.interp(width_m, PAD_GAP_M[::-1], DRIVER_ANGLE_RAD[::-1]))


def pose(R=np.eye(3), p=(0.0, 0.0, 0.0)) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, p
    return X


@dataclass
class SceneConfig:
    """What is on the table. `objects` (pairs of ObjectSpec and 4x4 X_task_object) places
    those objects as given (then settles them); otherwise `n_objects` are drawn with
    `seed`: procedural primitives, or URDF/OBJ files from `mesh_dir`, arranged `packed` or
    `pile` and settled (scenes.arrange). `object_mass_kg` > 0 overrides every mass."""

    seed: int = 0
    n_objects: int = 3
    arrangement: str = "packed"
    mesh_dir: str = ""
    object_mass_kg: float = 0.0
    objects: tuple = ()

    def validate(self):
        if self.arrangement not in ("packed", "pile"):
            raise ValueError(f"arrangement {self.arrangement!r}: use 'packed' or 'pile'")
        if not self.objects and not 1 <= self.n_objects <= 10:
            raise ValueError(f"n_objects {self.n_objects}: use 1..10")
        if not np.isfinite(self.object_mass_kg) or self.object_mass_kg < 0:
            raise ValueError(f"object_mass_kg {self.object_mass_kg}: use > 0, or 0 for each object's own")


@dataclass
class CameraSettings:
    """A fixed depth camera: optical frame at `position_m` looking at `target_m` (task
    frame), pinhole `width` x `height` px with focal length `focal_px` (VGN's camera)."""

    position_m: tuple = (0.15, -0.125, 0.526)  # 0.55 m from the table centre, 60 deg elevation
    target_m: tuple = (0.15, 0.15, TABLE_HEIGHT_M)
    width: int = 640
    height: int = 480
    focal_px: float = 540.0
    max_depth_m: float = 3.0


@dataclass
class WorldSettings:
    contact: SimSettings = field(default_factory=SimSettings)  # time step, contact model, friction
    camera: CameraSettings = field(default_factory=CameraSettings)
    home_tcp_m: tuple = (0.15, 0.15, 0.55)  # TCP (pointing down, open hand) after load/reset
    # The stand-in's reach: the TCP must stay in this box (task frame) and above the table.
    workspace_min_m: tuple = (-0.15, -0.15, TABLE_HEIGHT_M)
    workspace_max_m: tuple = (0.45, 0.45, 0.80)
    max_speed_mps: float = 0.25  # TCP speed cap (a request above it is slowed down)
    max_angular_speed_rad_s: float = 1.5
    max_contact_force_n: float = 60.0  # net contact force on the hand that stops a motion
    settle_time_s: float = 0.3  # after loading, with the hand at home

    def validate(self):
        self.contact.validate()
        lo, hi = np.asarray(self.workspace_min_m, float), np.asarray(self.workspace_max_m, float)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(lo < hi):
            raise ValueError("workspace_min_m must be below workspace_max_m on every axis (3 values each)")
        if not (self.max_speed_mps > 0 and self.max_angular_speed_rad_s > 0 and self.max_contact_force_n > 0):
            raise ValueError("max_speed_mps, max_angular_speed_rad_s and max_contact_force_n must be > 0")


@dataclass
class ObjectState:
    name: str
    X_task_object: np.ndarray  # 4x4
    mass_kg: float
    height_above_table_m: float  # lowest collision vertex above the table top
    in_hand: bool  # touches both fingers
    lifted: bool  # in the hand and >= 1 cm above the table
    out_of_workspace: bool  # outside the task cube's footprint, or below the table top
    grasp_mode: str = ""  # in the hand: "power" (palm or proximal links touch it) or "precision"


@dataclass
class FingerCommand:
    target_width_m: float
    speed_mps: float
    force_n: float
    t_start_s: float  # sim time the command arrived
    held: bool = False  # stopped where the fingers were (hold_fingers)


# ----------------------------------------------------------------------------------
# Drake systems


class FingerServoSystem(LeafSystem):
    """The 2F-85's motor on both driver joints (the coupler constraint ties them).

    Discrete state: the reference angle, which moves towards the target angle at the
    commanded rate every time step. Numeric parameters: [target angle rad, rate
    rad/s, torque limit N m]. Output: tau = clip(kp (ref - q), ±limit): the full
    torque (the grip force) is reached 2 mm short of the reference at 40 N. The damping
    is the driver joints' own (`DRIVER_DAMPING_NMS_PER_RAD`, set in
    build_world_diagram): SAP treats joint damping implicitly, whereas a damping term
    here is explicit and made the light linkage chatter at ±14 rad/s every step.
    """

    KP_NM_PER_RAD = 100.0  # 200 overshoots, 400 chatters (dt 2 ms)

    def __init__(self, plant, hand, time_step_s):
        super().__init__()
        self._iq = hand.driver_joints[0].position_start()
        self._dt = time_step_s
        self._state = self.DeclareVectorInputPort("state", plant.num_multibody_states())
        self._ref = self.DeclareDiscreteState(1)
        self._params = self.DeclareNumericParameter(BasicVector([0.0, 1.0, 1.0]))
        # Callbacks through a weak reference: a bound method held by the C++ side would
        # keep this object (and the C++ system it owns once its diagram is gone) alive.
        me = weakref.ref(self)
        self.DeclarePeriodicDiscreteUpdateEvent(time_step_s, 0.0, lambda c, s: me()._update(c, s))
        self.DeclareVectorOutputPort("actuation", 2, lambda c, out: me()._calc(c, out))

    def set_command(self, context, target_rad, rate_rad_s, torque_limit_nm):
        context.get_mutable_numeric_parameter(self._params).SetFromVector(
            [target_rad, rate_rad_s, torque_limit_nm])

    def set_reference(self, context, angle_rad):
        context.get_mutable_discrete_state(self._ref).SetFromVector([angle_rad])

    def reference(self, context) -> float:
        return context.get_discrete_state(self._ref).GetAtIndex(0)

    def command(self, context):
        return context.get_numeric_parameter(self._params).CopyToVector()

    def _update(self, context, discrete_state):
        target, rate, _ = context.get_numeric_parameter(self._params).CopyToVector()
        ref = context.get_discrete_state(self._ref).GetAtIndex(0)
        step = rate * self._dt
        discrete_state.get_mutable_vector(self._ref).SetAtIndex(
            0, ref + float(np.clip(target - ref, -step, step)))

    def _calc(self, context, output):
        x = self._state.Eval(context)
        ref = context.get_discrete_state(self._ref).GetAtIndex(0)
        limit = context.get_numeric_parameter(self._params).GetAtIndex(2)
        tau = self.KP_NM_PER_RAD * (ref - x[self._iq])
        tau = float(np.clip(tau, -limit, limit))
        output.SetFromVector([tau, tau])


@dataclass
class WorldDiagram:
    diagram: object
    plant: object
    scene_graph: object
    hand: object
    mount_body: object  # the hand's floating body (base_mount)
    object_bodies: list
    finger_servo: object
    # Geometries by GeometryId *value* (int): pydrake hands out GeometryIds that can
    # point into a vector the plant later grows (hand_model.Hand.geometry_links had
    # garbage ids, so the pad boxes were not recognised), so copy the values at once.
    hand_link_of: dict  # collision geometry id value -> hand link name
    hand_geometries: frozenset  # collision geometry id values of the hand
    finger_geometries: frozenset
    hand_bodies: frozenset  # BodyIndex of every hand link

    def release(self) -> None:
        """Let the garbage collector free this diagram; call only when discarding it (no
        system of it may be used after).

        pydrake (1.51) never frees a diagram that holds a Python LeafSystem: C++ keeps the
        Python system alive while the diagram lives, and the system keeps its builder and
        diagram alive through pydrake's reference-cycle bookkeeping, a cycle through C++
        that gc cannot see (+15 MB of RSS per load_scene in the sim bridge). Emptying the
        Python systems' attributes (that bookkeeping lives there) breaks it; their
        callbacks hold them only weakly (FingerServoSystem). tests/test_sim_world_memory.py
        measures that repeated resets stay flat.
        """
        for system in self.diagram.GetSystems():
            if not type(system).__module__.startswith("pydrake"):
                vars(system).clear()


def build_world_diagram(objects, settings: WorldSettings) -> WorldDiagram:
    """Plant (gravity, SAP, the paper's contact parameters) + scene graph + the finger
    servo. `objects`: list of (name, ObjectSpec). The table is a 1 m box whose top is the
    plane z = TABLE_HEIGHT_M; the hand floats (its pose is set by SimWorld each step)."""
    from pydrake.geometry import (AddContactMaterial, AddRigidHydroelasticProperties, Box,
                                  ProximityProperties)
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder

    s = settings.contact
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=s.time_step_s, discrete_contact_approximation="sap",
        contact_model="hydroelastic_with_fallback" if s.contact_model == "hydroelastic" else "point"),
        builder)
    props = proximity_properties(s)
    table_props = ProximityProperties()
    AddContactMaterial(dissipation=s.hunt_crossley_dissipation_s_per_m,
                       friction=CoulombFriction(TABLE_FRICTION, TABLE_FRICTION), properties=table_props)
    table_props.AddProperty("material", "relaxation_time", s.effective_relaxation_time_s())
    if s.contact_model == "hydroelastic":
        AddRigidHydroelasticProperties(0.01, table_props)
    X_table = RigidTransform([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M - 0.025])
    plant.RegisterCollisionGeometry(plant.world_body(), X_table, Box(1.0, 1.0, 0.05), "table", table_props)
    plant.RegisterVisualGeometry(plant.world_body(), X_table, Box(1.0, 1.0, 0.05), "table_visual",
                                 [0.6, 0.6, 0.6, 1.0])
    # Where removed objects are parked: a shelf far out of view (no visual geometry).
    X_shelf = RigidTransform([PARKING_SHELF_M[0] + 10.0, PARKING_SHELF_M[1], PARKING_SHELF_M[2] - 0.5])
    plant.RegisterCollisionGeometry(plant.world_body(), X_shelf, Box(21.0, 2.0, 1.0), "parking_shelf", table_props)
    hand = hand_model.add_hand(plant, scene_graph, props, floating=True,
                               pad_contact_points=s.contact_model == "point")
    bodies = [spec.add_to_plant(plant, name=name, proximity_properties=props) for name, spec in objects]
    plant.set_gravity_enabled(hand.model_instance, False)  # the arm carries the hand
    for j in hand.driver_joints:
        j.set_default_damping(DRIVER_DAMPING_NMS_PER_RAD)
    plant.Finalize()
    servo = builder.AddSystem(FingerServoSystem(plant, hand, s.time_step_s))
    builder.Connect(plant.get_state_output_port(), servo.get_input_port())
    builder.Connect(servo.get_output_port(), plant.get_actuation_input_port())
    diagram = builder.Build()
    link_of = {}
    for bi in plant.GetBodyIndices(hand.model_instance):
        body = plant.get_body(bi)
        for g in plant.GetCollisionGeometriesForBody(body):
            link_of[g.get_value()] = body.name()
    finger = frozenset(g for g, link in link_of.items() if link in FINGER_LINKS)
    return WorldDiagram(diagram, plant, scene_graph, hand, plant.GetBodyByName("base_mount", hand.model_instance),
                        bodies, servo, link_of, frozenset(link_of), finger,
                        frozenset(plant.GetBodyIndices(hand.model_instance)))


# ----------------------------------------------------------------------------------
# straight-line TCP motion


def _rotvec(R) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def _exp(w) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues; scipy's cost 0.25 ms per step)."""
    angle = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if angle < 1e-12:
        return np.eye(3)
    x, y, z = w[0] / angle, w[1] / angle, w[2] / angle
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _min_jerk(tau):
    """Position and rate (per unit duration) of the minimum-jerk profile at tau in [0,1]."""
    tau = min(max(tau, 0.0), 1.0)
    return 10 * tau**3 - 15 * tau**4 + 6 * tau**5, 30 * tau**2 - 60 * tau**3 + 30 * tau**4


class Motion:
    """One straight-line TCP motion; `done` is set with `result` = (success, message)."""

    PEAK_SPEED_FACTOR = 1.875  # peak / mean speed of the minimum-jerk profile

    def __init__(self, X_start, X_goal, t0_s, speed_mps, angular_speed_rad_s):
        self.X_start, self.X_goal, self.t0_s = np.asarray(X_start, float), np.asarray(X_goal, float), t0_s
        self.delta_p = self.X_goal[:3, 3] - self.X_start[:3, 3]
        self.delta_w = _rotvec(self.X_start[:3, :3].T @ self.X_goal[:3, :3])  # in the start frame
        self.length_m = float(np.linalg.norm(self.delta_p))
        self.duration_s = max(self.PEAK_SPEED_FACTOR * self.length_m / speed_mps,
                              self.PEAK_SPEED_FACTOR * float(np.linalg.norm(self.delta_w)) / angular_speed_rad_s,
                              1e-3)
        self.done = threading.Event()
        self.result = None
        self.travelled_m = 0.0

    def reference(self, t_s):
        """(X_task_tcp 4x4, v_task [3], w_task [3]) at sim time t_s."""
        s, ds = _min_jerk((t_s - self.t0_s) / self.duration_s)
        R0 = self.X_start[:3, :3]
        X = pose(R0 @ _exp(s * self.delta_w), self.X_start[:3, 3] + s * self.delta_p)
        rate = ds / self.duration_s if 0 <= t_s - self.t0_s <= self.duration_s else 0.0
        return X, rate * self.delta_p, rate * (R0 @ self.delta_w)

    def finished(self, t_s) -> bool:
        return t_s >= self.t0_s + self.duration_s

    def finish(self, success, message):
        self.result = (bool(success), message)
        self.done.set()


# ----------------------------------------------------------------------------------


class SimWorld:
    """A Drake world stepped by the caller (`advance`) or by a `RealTimeRunner` thread."""

    def __init__(self, scene_config: SceneConfig | None = None, settings: WorldSettings | None = None):
        self.settings = settings or WorldSettings()
        self.settings.validate()
        self._lock = threading.RLock()
        self._finger_command = None
        self._stall_since_s = self._blocked_angle = None
        self._motion = None
        self.reset(scene_config or SceneConfig())

    # -- scene ------------------------------------------------------------------------

    def reset(self, scene_config: SceneConfig) -> list:
        """Build the world for `scene_config` (drawing, arranging and settling objects);
        the hand goes home, open. Returns the object names. On an error the current
        world stays."""
        scene_config.validate()
        named, poses = self._draw_scene(scene_config)
        with self._lock:
            if self._motion is not None and not self._motion.done.is_set():
                self._motion.finish(False, "interrupted: the scene was reloaded")
            old = getattr(self, "w", None)
            self.w = build_world_diagram(named, self.settings)
            self.scenes_loaded = getattr(self, "scenes_loaded", 0) + 1
            self.scene_config = scene_config
            self.names = [n for n, _ in named]
            self._specs = {n: spec for n, spec in named}
            self._hull_vertices = {n: spec.collision_mesh().convex_hull.vertices for n, spec in named}
            self._removed = set()
            self._meshes = None  # visual meshes for the camera, loaded at the first frame
            self._make_simulator()
            X = self.w.plant.CalcRelativeTransform(self.w.plant.CreateDefaultContext(), self.w.hand.tcp_frame,
                                                   self.w.mount_body.body_frame())
            self._X_tcp_mount = X.GetAsMatrix4()
            pc = self._plant_context()
            # The stand-in's mass: see STAND_IN_MASS_KG.
            from pydrake.multibody.tree import SpatialInertia

            self.w.mount_body.SetSpatialInertiaInBodyFrame(
                pc, SpatialInertia.SolidBoxWithMass(STAND_IN_MASS_KG, 0.1, 0.1, 0.1))
            for body, X in zip(self.w.object_bodies, poses):
                self.w.plant.SetFreeBodyPose(pc, body, _rigid(X))
            self._hold = pose(R_TOP_DOWN, self.settings.home_tcp_m)
            self._motion = None
            self._set_hand_state(self._hold, np.zeros(3), np.zeros(3))
            self._finger_command = None
            self._stall_since_s = self._blocked_angle = None
            self.w.finger_servo.set_command(self._servo_context(), 0.0, 1.0,
                                            driver_torque_nm(self.settings.contact.grip_force_n))
            self.simulator.Initialize()
            self._advance_locked(self.settings.settle_time_s)
            names = list(self.names)
        if old is not None:  # free the previous scene's diagram now (see WorldDiagram.release)
            old.release()
            del old
            gc.collect()
            _return_freed_memory()
        return names

    def _draw_scene(self, cfg: SceneConfig):
        from .objects import load_mesh_object, random_procedural_objects

        if cfg.objects:
            specs = [spec for spec, _ in cfg.objects]
            poses = [np.asarray(X, float) for _, X in cfg.objects]
        else:
            if cfg.mesh_dir:
                import pathlib

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

    def _make_simulator(self):
        from pydrake.systems.analysis import Simulator

        self.simulator = Simulator(self.w.diagram)

    def _plant_context(self):
        return self.w.plant.GetMyMutableContextFromRoot(self.simulator.get_mutable_context())

    def _servo_context(self):
        return self.w.finger_servo.GetMyMutableContextFromRoot(self.simulator.get_mutable_context())

    # -- time ---------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        with self._lock:
            return self.simulator.get_context().get_time()

    def advance(self, duration_s: float) -> None:
        """Simulate `duration_s` more seconds (arm motion, fingers, objects)."""
        with self._lock:
            self._advance_locked(duration_s)

    def _advance_locked(self, duration_s):
        dt = self.settings.contact.time_step_s
        t_end = self.time_s + duration_s
        while self.time_s < t_end - 1e-9:
            self._step(dt)

    def _step(self, dt):
        t = self.time_s
        m = self._motion
        if m is not None and not m.done.is_set():
            X, v, w = m.reference(t)
            self._set_hand_state(X, v, w)
            self.simulator.AdvanceTo(t + dt)
            force = self.hand_contact_force_n()
            if np.linalg.norm(force) > self.settings.max_contact_force_n:
                X_now = self.tcp_pose()
                self._hold = X_now
                done = float(np.linalg.norm(X_now[:3, 3] - m.X_start[:3, 3]))
                m.finish(False, f"stopped by contact after {done:.3f} of {m.length_m:.3f} m: "
                                f"{np.linalg.norm(force):.0f} N on the hand exceeds the "
                                f"{self.settings.max_contact_force_n:.0f} N limit")
            elif m.finished(self.time_s):
                self._hold = m.X_goal
                m.finish(True, f"reached the target ({m.length_m:.3f} m in {m.duration_s:.2f} s)")
        else:
            self._set_hand_state(self._hold, np.zeros(3), np.zeros(3))
            self.simulator.AdvanceTo(t + dt)
        self._update_stall()

    def _set_hand_state(self, X_task_tcp, v_task, w_task):
        """The stand-in: put the hand's floating body where the TCP reference says."""
        from pydrake.multibody.math import SpatialVelocity

        plant, pc = self.w.plant, self._plant_context()
        X_tcp_mount = self._X_tcp_mount
        X_mount = X_task_tcp @ X_tcp_mount
        p_tcp_mount_W = X_task_tcp[:3, :3] @ X_tcp_mount[:3, 3]
        plant.SetFreeBodyPose(pc, self.w.mount_body, _rigid(X_mount))
        plant.SetFreeBodySpatialVelocity(pc, self.w.mount_body, SpatialVelocity(
            np.asarray(w_task, float), np.asarray(v_task, float) + _cross(w_task, p_tcp_mount_W)))

    # -- arm ----------------------------------------------------------------------

    def tcp_pose(self) -> np.ndarray:
        """Current X_task_tcp (4x4)."""
        with self._lock:
            pc = self._plant_context()
            return self.w.plant.CalcRelativeTransform(pc, self.w.plant.world_frame(),
                                                      self.w.hand.tcp_frame).GetAsMatrix4()

    def check_reachable(self, X_task_tcp) -> tuple:
        """(reachable, message): the stand-in reaches a TCP pose inside its workspace box
        and not below the table top."""
        X = np.asarray(X_task_tcp, float)
        if X.shape != (4, 4) or not np.isfinite(X).all():
            return False, "target pose is not a finite 4x4 transform"
        R = X[:3, :3]
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            return False, "target rotation is not a proper rotation (normalise the quaternion)"
        p = X[:3, 3]
        if p[2] < TABLE_HEIGHT_M:
            return False, f"target TCP z = {p[2]:.3f} m is below the table top ({TABLE_HEIGHT_M} m)"
        lo, hi = np.asarray(self.settings.workspace_min_m), np.asarray(self.settings.workspace_max_m)
        if np.any(p < lo) or np.any(p > hi):
            box = "..".join("(" + ", ".join(f"{v:.2f}" for v in b) + ")" for b in (lo, hi))
            return False, (f"target TCP ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m is outside the arm "
                           f"stand-in's workspace {box} m")
        return True, "reachable"

    def start_move(self, X_task_tcp, speed_mps: float) -> Motion:
        """Start a straight-line TCP motion from the current reference; returns the Motion
        (finished later by stepping). An unreachable target or a bad speed gives a Motion
        that is already done with success False."""
        ok, msg = self.check_reachable(X_task_tcp)
        if ok and not (np.isfinite(speed_mps) and speed_mps > 0):
            ok, msg = False, f"speed_mps {speed_mps}: must be > 0"
        with self._lock:
            if self._motion is not None and not self._motion.done.is_set():
                ok, msg = False, "another motion is running"
            speed = min(float(speed_mps), self.settings.max_speed_mps) if ok else 1.0
            m = Motion(self._hold, np.asarray(X_task_tcp, float) if ok else self._hold, self.time_s,
                       speed, self.settings.max_angular_speed_rad_s)
            if not ok:
                m.finish(False, msg)
            else:
                self._motion = m
            return m

    def stop_motion(self) -> bool:
        """Halt the running motion at once where the reference is now (an arm's protective
        stop); it ends with success False, "stopped on request". False if none ran."""
        with self._lock:
            m = self._motion
            if m is None or m.done.is_set():
                return False
            self._hold = m.reference(self.time_s)[0]
            m.finish(False, "stopped on request")
            return True

    def move_tcp(self, X_task_tcp, speed_mps: float, timeout_s: float = 30.0) -> tuple:
        """Move along a straight line, stepping the simulation here; (success, message)."""
        m = self.start_move(X_task_tcp, speed_mps)
        with self._lock:
            t_end = self.time_s + timeout_s
            while not m.done.is_set() and self.time_s < t_end:
                self._advance_locked(0.01)
        if not m.done.is_set():
            with self._lock:
                self._hold = self.tcp_pose()
                m.finish(False, f"did not finish within {timeout_s} s of simulated time")
        return m.result

    def hand_contact_force_n(self) -> np.ndarray:
        """Net contact force [N] on the hand from everything else (task frame): a wrist
        force sensor's reading, without the hand's own weight."""
        with self._lock:
            total = np.zeros(3)
            for _, _, force in self._hand_contacts():
                total += force
            return total

    def _hand_contacts(self):
        """(hand geometry id value, other geometry id value, force on the hand [3] N)
        per contact between the hand and something else."""
        plant, pc = self.w.plant, self._plant_context()
        results = plant.get_contact_results_output_port().Eval(pc)
        hand_g = self.w.hand_geometries
        out = []
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            surf = info.contact_surface()
            f_M = info.F_Ac_W().translational()  # on the body of geometry M
            m, n = surf.id_M().get_value(), surf.id_N().get_value()
            if m in hand_g and n not in hand_g:
                out.append((m, n, f_M))
            elif n in hand_g and m not in hand_g:
                out.append((n, m, -f_M))
        hand_bodies = self.w.hand_bodies
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            a_in, b_in = info.bodyA_index() in hand_bodies, info.bodyB_index() in hand_bodies
            f_B = info.contact_force()  # on body B
            pp = info.point_pair()
            if b_in and not a_in:
                out.append((pp.id_B.get_value(), pp.id_A.get_value(), f_B))
            elif a_in and not b_in:
                out.append((pp.id_A.get_value(), pp.id_B.get_value(), -f_B))
        return out

    def _hand_contact_pairs(self):
        """(hand geometry id value, other geometry id value) of every hand contact."""
        plant, pc = self.w.plant, self._plant_context()
        results = plant.get_contact_results_output_port().Eval(pc)
        hand_g = self.w.hand_geometries
        pairs = []
        for i in range(results.num_hydroelastic_contacts()):
            surf = results.hydroelastic_contact_info(i).contact_surface()
            m, n = surf.id_M().get_value(), surf.id_N().get_value()
            for a, b in ((m, n), (n, m)):
                if a in hand_g and b not in hand_g:
                    pairs.append((a, b))
        for i in range(results.num_point_pair_contacts()):
            pp = results.point_pair_contact_info(i).point_pair()
            ga, gb = pp.id_A.get_value(), pp.id_B.get_value()
            for a, b in ((ga, gb), (gb, ga)):
                if a in hand_g and b not in hand_g:
                    pairs.append((a, b))
        return pairs

    # -- fingers ------------------------------------------------------------------

    def command_fingers(self, target_width_m: float, speed_mps: float, force_n: float) -> None:
        """Move the fingers towards an opening [m] at a speed [m/s of opening], squeezing at
        most `force_n` [N] (a new target restarts the stall detection)."""
        with self._lock:
            cmd = self._finger_command
            if cmd is None or (cmd.target_width_m, cmd.speed_mps, cmd.force_n) != (target_width_m, speed_mps, force_n):
                self._finger_command = FingerCommand(target_width_m, speed_mps, force_n, self.time_s)
                self._stall_since_s = self._blocked_angle = None
                ctx = self._servo_context()
                if cmd is None:  # first command: start the reference where the fingers are
                    self.w.finger_servo.set_reference(ctx, self.driver_angle_rad())
                self.w.finger_servo.set_command(
                    ctx, driver_angle_for_width(target_width_m),
                    max(speed_mps, 1e-3) / GAP_PER_DRIVER_RAD_M, driver_torque_nm(force_n))

    def hold_fingers(self) -> None:
        """Stop the fingers where they are (the 2F-85's rGTO = 0; its drive self-locks)."""
        with self._lock:
            if self._finger_command is None:
                return
            angle = self.driver_angle_rad()
            ctx = self._servo_context()
            _, rate, torque = self.w.finger_servo.command(ctx)
            self.w.finger_servo.set_reference(ctx, angle)
            self.w.finger_servo.set_command(ctx, angle, rate, torque)
            self._finger_command = FingerCommand(width_from_driver_angle(angle), self._finger_command.speed_mps,
                                                 self._finger_command.force_n, self.time_s, held=True)

    def driver_angle_rad(self) -> float:
        with self._lock:
            return self.w.hand.driver_angle_rad(self.w.plant, self._plant_context())

    def finger_width_m(self) -> float:
        return width_from_driver_angle(self.driver_angle_rad())

    def _driver_rate(self):
        pc = self._plant_context()
        iv = self.w.hand.driver_joints[0].velocity_start()
        return float(self.w.plant.GetVelocities(pc)[iv])

    STALL_RATE_RAD_S = 0.05
    STALL_HOLD_S = 0.04  # stalled this long = stopped
    START_GRACE_S = 0.06  # after a new command, before a stop can be declared
    BLOCK_RELEASE_RAD = 0.02  # ~2 mm of opening: fingers moving on from an object

    def _update_stall(self):
        if self._finger_command is None:
            return
        if abs(self._driver_rate()) < self.STALL_RATE_RAD_S:
            if self._stall_since_s is None:
                self._stall_since_s = self.time_s
        else:
            self._stall_since_s = None

    def finger_status(self) -> tuple:
        """(width_m, state) with state 'moving', 'at_target' or 'blocked' (stopped short
        of the target: on an object, or with the fingers touching each other)."""
        with self._lock:
            cmd = self._finger_command
            width = self.finger_width_m()
            if cmd is None:
                return width, "at_target"
            target_angle = driver_angle_for_width(cmd.target_width_m)
            if self._blocked_angle is not None:
                # Once stopped on an object, stay so while the fingers keep still: a lift
                # that flexes the fingers for a moment is no dropped object. Only moving
                # on towards the target (the object slipped out) ends it, as on the 2F-85.
                if abs(self.driver_angle_rad() - self._blocked_angle) < self.BLOCK_RELEASE_RAD:
                    return width, "blocked"
                self._blocked_angle = None
                self._stall_since_s = None
            t = self.time_s
            # Stopped = stalled while the motor pushes with its full torque towards the
            # target. Right after a reversal (open after a squeeze) the fingers stall too,
            # until the servo reference has come back past them: that is no stop.
            stopped = (self._stall_since_s is not None and t - self._stall_since_s >= self.STALL_HOLD_S
                       and t - cmd.t_start_s >= self.START_GRACE_S and self._pushing(target_angle))
            close_enough = abs(self.driver_angle_rad() - target_angle) < 0.01
            if close_enough and (stopped or t - cmd.t_start_s >= self.START_GRACE_S):
                return cmd.target_width_m, "at_target"
            if stopped:
                # Stopped short of the target: on an object, or on the other finger (the
                # pads or fingertips meet when closing on nothing; where depends on how
                # the underactuated fingers folded: 1.1 mm from open, 3.7 mm after a
                # fingertip pinch lost its object). Either way the 2F-85 reports an
                # object (gOBJ 2) at its motor position; telling them apart is the
                # executor's job (robotiq_driver.grip_calibration).
                self._blocked_angle = self.driver_angle_rad()
                return width, "blocked"
            return width, "moving"

    def _pushing(self, target_angle) -> bool:
        """The finger servo's torque is (nearly) at its limit, towards the target."""
        ctx = self._servo_context()
        _, _, limit = self.w.finger_servo.command(ctx)
        q = self.driver_angle_rad()
        tau = FingerServoSystem.KP_NM_PER_RAD * (self.w.finger_servo.reference(ctx) - q)
        return tau * (target_angle - q) > 0 and abs(tau) >= 0.9 * limit

    def fingers_busy(self) -> bool:
        """True while the fingers move or the servo is still building up its grip."""
        with self._lock:
            if self._finger_command is None:
                return False
            target, _, _ = self.w.finger_servo.command(self._servo_context())
            ref = self.w.finger_servo.reference(self._servo_context())
            return abs(ref - target) > 1e-9 or self.finger_status()[1] == "moving"

    def finger_plant(self, advances_time: bool = True) -> "SimFingerPlant":
        """A robotiq_driver FingerPlant backed by this world. With `advances_time` each
        `advance(dt)` also simulates dt (the emulator's clock drives the sim); without,
        something else (a RealTimeRunner) steps the world."""
        return SimFingerPlant(self, advances_time)

    # -- objects ------------------------------------------------------------------

    def _object_poses(self):
        pc = self._plant_context()
        return {n: self.w.plant.EvalBodyPoseInWorld(pc, b).GetAsMatrix4()
                for n, b in zip(self.names, self.w.object_bodies)}

    def _body(self, name):
        if name not in self.names or name in self._removed:
            raise KeyError(f"no object named {name!r}; objects: {', '.join(self.object_names())}")
        return self.w.object_bodies[self.names.index(name)]

    def object_names(self) -> list:
        with self._lock:
            return [n for n in self.names if n not in self._removed]

    def object_states(self) -> list:
        """Ground truth for every object still in the scene (removed ones are left out)."""
        with self._lock:
            poses = self._object_poses()
            touching = {}
            left = {g for g, l in self.w.hand_link_of.items() if l.startswith("left_")}
            right = {g for g, l in self.w.hand_link_of.items() if l.startswith("right_")}
            geom_owner = {}
            for n, b in zip(self.names, self.w.object_bodies):
                for g in self.w.plant.GetCollisionGeometriesForBody(b):
                    geom_owner[g.get_value()] = n
            inner = set(hand_model.PALM_LINKS) | set(hand_model.PROXIMAL_LINKS)  # as grasp_simulation's modes
            wrapped = set()
            for h, other in self._hand_contact_pairs():
                n = geom_owner.get(other)
                if n is not None:
                    touching.setdefault(n, set()).add("left" if h in left else "right" if h in right else "palm")
                    if self.w.hand_link_of.get(h) in inner:
                        wrapped.add(n)
            pc = self._plant_context()
            out = []
            for n, b in zip(self.names, self.w.object_bodies):
                if n in self._removed:
                    continue
                X = poses[n]
                v = self._hull_vertices[n] @ X[:3, :3].T + X[:3, 3]
                height = float(v[:, 2].min() - TABLE_HEIGHT_M)
                in_hand = {"left", "right"} <= touching.get(n, set())
                c = v.mean(0)
                out_ws = bool(c[0] < 0 or c[0] > VOLUME_SIZE_M or c[1] < 0 or c[1] > VOLUME_SIZE_M
                              or v[:, 2].max() < TABLE_HEIGHT_M)
                mode = ("power" if n in wrapped else "precision") if in_hand else ""
                out.append(ObjectState(n, X, float(b.get_mass(pc)), height, in_hand,
                                       in_hand and height >= 0.01, out_ws, mode))
            return out

    def set_object_mass(self, name: str, mass_kg: float) -> None:
        """Scale an object's mass (and inertia) to `mass_kg`; name '' = every object."""
        from pydrake.multibody.tree import RotationalInertia, SpatialInertia

        if not (np.isfinite(mass_kg) and mass_kg > 0):
            raise ValueError(f"mass_kg {mass_kg}: must be > 0")
        with self._lock:
            names = self.object_names() if name == "" else [name]
            bodies = [self._body(n) for n in names]
            pc = self._plant_context()
            for n, body in zip(names, bodies):
                spec = self._specs[n].with_mass(mass_kg)
                I = spec.inertia_kg_m2
                M = SpatialInertia.MakeFromCentralInertia(
                    spec.mass_kg, spec.com_m,
                    RotationalInertia(I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]))
                body.SetSpatialInertiaInBodyFrame(pc, M)

    def remove_object(self, name: str) -> None:
        """Take an object out of the scene (the clutter-removal benchmark does this after
        a successful grasp): it is put down on a shelf far out of view, 0.5 m from the
        previous one. (Locking the body instead made a later SAP step crash in libdrake.)"""
        with self._lock:
            body = self._body(name)
            pc = self._plant_context()
            k = len(self._removed)
            x, y, z = PARKING_SHELF_M
            self.w.plant.SetFreeBodyPose(pc, body, _rigid(pose(p=(x + 0.5 * k, y, z + 0.2))))
            self.w.plant.SetFreeBodySpatialVelocity(pc, body, _zero_velocity())
            self._removed.add(name)

    # -- camera -------------------------------------------------------------------

    def camera_pose(self) -> np.ndarray:
        from .depth_rendering import look_at

        c = self.settings.camera
        return look_at(c.position_m, c.target_m)

    def intrinsics(self):
        """gravgrasp_detector.tsdf.CameraIntrinsics of the camera (what TSDFVolume.integrate takes)."""
        from gravgrasp_detector.tsdf import CameraIntrinsics

        c = self.settings.camera
        return CameraIntrinsics(c.width, c.height, c.focal_px, c.focal_px, (c.width - 1) / 2, (c.height - 1) / 2)

    def render_depth(self) -> tuple:
        """(depth float32 HxW [m], 0 = no return; CameraIntrinsics; T_task_camera 4x4) of
        the table, the objects and the hand as they are now."""
        from .depth_rendering import DepthRenderer

        with self._lock:
            posed = self._posed_visual_meshes()
        T = self.camera_pose()
        k = self.intrinsics()
        depth = DepthRenderer(posed).render(k, T, self.settings.camera.max_depth_m)
        return depth, k, T

    def _posed_visual_meshes(self):
        """(trimesh, X_task_mesh) for the table, every object in the scene and every hand link."""
        plant, pc = self.w.plant, self._plant_context()
        if self._meshes is None:
            self._meshes = self._visual_meshes()
        cache = self._meshes
        out = [(cache["table"], np.eye(4))]
        for n, b in zip(self.names, self.w.object_bodies):
            if n not in self._removed:
                out.append((cache["objects"][n], plant.EvalBodyPoseInWorld(pc, b).GetAsMatrix4()))
        for body, mesh, X_BG in cache["hand"]:
            out.append((mesh, plant.EvalBodyPoseInWorld(pc, body).GetAsMatrix4() @ X_BG))
        return out

    def _visual_meshes(self):
        import trimesh

        table = trimesh.creation.box((1.0, 1.0, 0.05))
        table.apply_translation([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M - 0.025])
        objects = {}
        for n in self.names:
            spec = self._specs[n]
            objects[n] = (trimesh.load(spec.visual_mesh_path, force="mesh") if spec.visual_mesh_path
                          else spec.collision_mesh())
        plant, inspector = self.w.plant, self.w.scene_graph.model_inspector()
        hand = []
        for bi in plant.GetBodyIndices(self.w.hand.model_instance):
            body = plant.get_body(bi)
            for gid in plant.GetVisualGeometriesForBody(body):
                mesh = _shape_mesh(inspector.GetShape(gid))
                if mesh is not None:
                    hand.append((body, mesh, inspector.GetPoseInFrame(gid).GetAsMatrix4()))
        return {"table": table, "objects": objects, "hand": hand}


def _shape_mesh(shape):
    """trimesh of a Drake shape in its geometry frame (None for shapes a camera would not
    see or that we do not draw)."""
    import trimesh
    from pydrake.geometry import Box, Capsule, Convex, Cylinder, Mesh, Sphere

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


def _return_freed_memory():
    """Hand freed heap pages back to the OS (glibc malloc_trim; elsewhere nothing). A
    scene is ~15 MB of small allocations, and the sim node reloads it from whichever
    executor thread serves load_scene: each thread's malloc arena kept its freed scene,
    +75 MB over 4 reloads in a 10 min soak, until trimmed."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _rigid(X):
    from pydrake.math import RigidTransform

    return RigidTransform(np.asarray(X, float))


def _zero_velocity():
    from pydrake.multibody.math import SpatialVelocity

    return SpatialVelocity(np.zeros(3), np.zeros(3))


class SimFingerPlant:
    """robotiq_driver.gripper_emulator.FingerPlant backed by a SimWorld: the emulator's
    commanded opening, speed and force drive the simulated actuator; the reading is the
    simulated driver angle as an opening, `blocked` when the fingers stopped on an object
    short of the target, and 0.10 A while they move (0 once stopped: the 2F-85's drive is
    self-locking).

    With `advances_time`, `advance(dt)` commands the world and simulates dt itself. Without,
    a RealTimeRunner steps the world, and `advance` never waits for it: the command goes
    into a mailbox the runner applies before its next chunk, and the reading is the one the
    runner took after its last chunk (a Modbus answer must not wait for the physics). Until
    the runner has taken a reading for the latest command, the fingers read as moving.
    """

    MOVING_CURRENT_A = 0.10

    def __init__(self, world: SimWorld, advances_time: bool = True):
        self.world = world
        self.advances_time = advances_time
        self.last_call_wall_s = None
        self._pending = None  # (target m, speed m/s, force N): the emulator's latest command
        self._applied = None  # the command the world runs (what the runner last applied)
        self._snapshot = None  # (the command it answers, FingerReading)

    def _reading(self, width, state):
        from robotiq_driver.gripper_emulator import FingerReading

        return FingerReading(width, state == "blocked", self.MOVING_CURRENT_A if state == "moving" else 0.0)

    def advance(self, dt_s, width_m, target_width_m, speed_mps, force_n):
        from robotiq_driver.gripper_emulator import FingerReading

        self.last_call_wall_s = time.monotonic()
        command = (float(target_width_m), float(speed_mps), float(force_n))
        if self.advances_time:
            self.world.command_fingers(*command)
            if dt_s > 0:
                self.world.advance(dt_s)
            return self._reading(*self.world.finger_status())
        self._pending = command
        snapshot = self._snapshot
        if snapshot is None or snapshot[0] != command:
            width = snapshot[1].width_m if snapshot is not None else width_m
            return FingerReading(width, False, self.MOVING_CURRENT_A)
        return snapshot[1]

    def apply_command(self) -> None:
        """Runner thread: hand the emulator's latest command to the world."""
        pending = self._pending
        if pending is not None:
            self.world.command_fingers(*pending)
            self._applied = pending

    def take_reading(self) -> None:
        """Runner thread: the reading `advance` answers with until the next one, tagged
        with the command the world ran. (Tagged with the latest *pending* one, a command
        that arrived between apply and read got the previous command's reading: an open
        right after a grip read as "stopped on an object while opening" at once.)"""
        self._snapshot = (self._applied, self._reading(*self.world.finger_status()))

    def idle_for_s(self) -> float:
        """Wall seconds since the emulator last drove the fingers (inf: never)."""
        return np.inf if self.last_call_wall_s is None else time.monotonic() - self.last_call_wall_s


class RealTimeRunner:
    """Steps a SimWorld in its own thread, paced to the wall clock (never faster than
    `real_time_rate`; slower when the physics cannot keep up). While nothing moves (no arm
    motion, fingers idle, every body slower than 1 mm/s) it does not step, so an idle
    scene costs no CPU (a held object at rest included). If the emulator stops driving the fingers (rGTO = 0, a fault) for
    `finger_idle_hold_s`, the fingers are stopped where they are."""

    CHUNK_S = 0.006  # simulated per lock hold (3 steps at 2 ms, ~6-15 ms of wall time)
    YIELD_S = 0.001

    def __init__(self, world: SimWorld, finger_plant: SimFingerPlant | None = None,
                 real_time_rate: float = 1.0, finger_idle_hold_s: float = 0.1):
        self.world, self.finger_plant = world, finger_plant
        self.real_time_rate = real_time_rate
        self.finger_idle_hold_s = finger_idle_hold_s
        self._stop = threading.Event()
        self._thread = None
        self.sim_s = 0.0  # simulated seconds stepped by this runner
        self.wall_busy_s = 0.0  # wall seconds spent stepping
        self.error = None

    def start(self) -> "RealTimeRunner":
        self._thread = threading.Thread(target=self._run, name="sim-world", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def real_time_factor(self) -> float:
        """Simulated seconds per wall second while stepping."""
        return self.sim_s / self.wall_busy_s if self.wall_busy_s > 0 else float("nan")

    def _busy(self) -> bool:
        w = self.world
        if w._motion is not None and not w._motion.done.is_set():
            return True
        if w.fingers_busy():
            return True
        v = w.w.plant.GetVelocities(w._plant_context())
        return bool(np.abs(v).max(initial=0.0) > 1e-3)

    def _run(self):
        sim_wall_offset = None
        try:
            while not self._stop.is_set():
                fp = self.finger_plant
                with self.world._lock:
                    if fp is not None:
                        if fp.idle_for_s() < self.finger_idle_hold_s:
                            fp.apply_command()
                        elif self.world._finger_command is not None and not self.world._finger_command.held:
                            self.world.hold_fingers()
                    busy = self._busy()
                    if busy:
                        t0 = time.monotonic()
                        self.world._advance_locked(self.CHUNK_S)
                        self.wall_busy_s += time.monotonic() - t0
                        self.sim_s += self.CHUNK_S
                    if fp is not None:
                        fp.take_reading()
                if not busy:
                    sim_wall_offset = None
                    self._stop.wait(self.CHUNK_S)
                    continue
                # Let waiting threads (services, the publisher) take the lock: a released
                # lock is not handed over, and re-taking it at once starved them.
                time.sleep(self.YIELD_S)
                # pace: sim time since the busy period began must not run ahead of wall time
                now = time.monotonic()
                if sim_wall_offset is None:
                    sim_wall_offset = (now, self.sim_s)
                ahead = (self.sim_s - sim_wall_offset[1]) / self.real_time_rate - (now - sim_wall_offset[0])
                if ahead > 0:
                    self._stop.wait(ahead)
        except Exception as e:  # reported by the node; the world is left as it was
            self.error = e
