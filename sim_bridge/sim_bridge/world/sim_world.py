"""The simulated robot cell behind the sim bridge: a Drake world with gravity, a table, a
scene of objects and the underactuated 2F-85 carried by an arm stand-in. No rclpy.

    world = SimWorld(SceneConfig(seed=3, n_objects=4), WorldSettings())
    world.move_tcp(X_task_tcp, speed_mps=0.1)        # (success, message)
    plant = SimFingerPlant(world)                      # robotiq FingerPlant backed by physics
    depth, intrinsics, T_task_camera = world.render_depth()
    world.object_states()                              # ground truth

Frames: everything is in the task frame (z up, origin at a corner of the 0.30 m cube,
table top at z = scenes.TABLE_HEIGHT_M); the Drake world frame *is* the task frame.

Arm stand-in (as in the paper's simulated benchmark, a free-floating hand on Cartesian
paths): the hand is a floating body whose pose and velocity are *set* before every time
step from a straight-line, minimum-jerk TCP reference (translation along a line,
rotation along the geodesic; `motion`), like a MuJoCo mocap body. This is an infinitely
stiff position-controlled arm: nothing sags under a heavy object, and there are no
stand-in gains to tune against SAP (a stiff explicit PD on the floating base needs gains
near the explicit-stability limit at dt = 2 ms and still sagged degrees under a 1.5 kg
object in a side grasp). Gravity is off for the hand only (the arm carries it). The
fingers stay fully dynamic (`fingers`) and the contacts are SAP's. The net contact force
on the hand links (what a wrist force/torque sensor reads) stops a motion when its
magnitude has grown by more than `max_contact_force_n` since the motion began, the rule
the UR adapter (gravgrasp_detector.execution.ur_arm) applies to its arm's TCP force: a lift that
starts with the closed fingers pressing on the table is not stopped by the press it
relieves, nor a shake by the weight already in the hand.

SimWorld is the one object the rest uses; it holds the Drake simulator and the scene,
and hands the parts to: `fingers.Fingers` (the finger servo and what the gripper
reports), `contacts` (hand contacts, object states), `camera` (depth images),
`scene_objects` (drawing a scene), `motion` (TCP motions, reach), `out_of_play` (removed
objects and those gone past the table, taken out of the physics), `resting_objects`
(freezing objects at rest).

Thread safety: every public method takes one lock (`SimWorld.lock`), so a `RealTimeRunner` thread can
step the world while other threads command it and read from it.
"""

from __future__ import annotations

import copy
import ctypes
import dataclasses
import gc
import threading

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.tree import RotationalInertia, SpatialInertia
from pydrake.systems.analysis import Simulator

from .camera import SceneMeshes, camera_intrinsics, camera_pose, render_depth
from .config import R_TOP_DOWN, SceneConfig, WorldSettings, pose
from .contacts import finger_squeeze_n, hand_contacts, hand_touches, object_states
from .diagram import build_world_diagram
from .fingers import Fingers
from .motion import Motion, check_reachable
from .out_of_play import OutOfPlay
from .parallel_grip import GripVerdict, judge_parallel_grip
from .resting_objects import RestingObjects
from .scene_objects import draw_scene

# The hand's floating body weighs this much in the simulation. Its state is reset every
# step, but within a step SAP moves it under the contact forces: at its real 0.8 kg a held
# 0.3 kg object dragged it down 12 um per step, which the reset turned into a 6 mm/s slip
# of the object in the grasp. At 1000 kg the same load gives 6 um/s.
STAND_IN_MASS_KG = 1000.0



@dataclasses.dataclass(frozen=True)
class WorldCheckpoint:
    """A saved SimWorld state (`SimWorld.checkpoint`); opaque to callers."""
    context: object
    world: dict
    fingers: dict
    resting: object
    resting_state: object
    out_of_play: tuple

class SimWorld:
    """A Drake world stepped by the caller (`advance`) or by a `RealTimeRunner` thread.

    Every public method takes `lock` (re-entrant); hold it to make several calls one
    atomic step, as the runner does."""

    def __init__(self, scene_config: SceneConfig | None = None, settings: WorldSettings | None = None):
        self.settings = settings or WorldSettings()
        self.settings.validate()
        self.lock = threading.RLock()
        self._motion = None
        self.scenes_loaded = 0  # how many scenes were loaded (reset)
        self.reset(scene_config or SceneConfig())

    # -- scene ------------------------------------------------------------------------

    def reset(self, scene_config: SceneConfig) -> list:
        """Build the world for `scene_config` (drawing, arranging and settling objects);
        the hand goes home, open. Returns the object names. On an error the current
        world stays."""
        scene_config.validate()
        named, poses = draw_scene(scene_config)
        with self.lock:
            if self._motion is not None and not self._motion.done.is_set():
                self._motion.finish(False, "interrupted: the scene was reloaded")
            old = getattr(self, "_model", None)
            self._model = build_world_diagram(named, self.settings)
            self.scenes_loaded += 1  # a new diagram: what was rendered or cached is stale
            self.scene_config = scene_config
            self.names = [n for n, _ in named]
            self._specs = {n: spec for n, spec in named}
            self._hull_vertices = {n: spec.collision_mesh().convex_hull.vertices for n, spec in named}
            self._removed = set()
            self._meshes = SceneMeshes(self._model, self._specs)  # loaded at the first frame
            self.simulator = Simulator(self._model.diagram)
            X = self._model.plant.CalcRelativeTransform(self._model.plant.CreateDefaultContext(), self._model.hand.tcp_frame,
                                                   self._model.mount_body.body_frame())
            self._X_tcp_mount = X.GetAsMatrix4()
            pc = self._plant_context()
            # The stand-in's mass: see STAND_IN_MASS_KG.
            self._model.mount_body.SetSpatialInertiaInBodyFrame(
                pc, SpatialInertia.SolidBoxWithMass(STAND_IN_MASS_KG, 0.1, 0.1, 0.1))
            for body, X in zip(self._model.object_bodies, poses):
                self._model.plant.SetFreeBodyPose(pc, body, _rigid(X))
            self._hold = pose(R_TOP_DOWN, self.settings.home_tcp_m)
            self._motion = None
            self._set_hand_state(self._hold, np.zeros(3), np.zeros(3))
            self._fingers = Fingers(self._model, self.simulator, self.settings.contact.grip_force_n)
            self._resting = None
            self.freeze_resting_objects(self.settings.freeze_resting_objects)
            self._out_of_play = OutOfPlay(self._model, self._scene_graph_context(), self.names, self._hull_vertices)
            self.simulator.Initialize()
            self._advance_locked(self.settings.settle_time_s)
            names = list(self.names)
        if old is not None:  # free the previous scene's diagram now (see WorldDiagram.release)
            old.release()
            del old
            gc.collect()
            _return_freed_memory()
        return names

    def _plant_context(self):
        return self._model.plant.GetMyMutableContextFromRoot(self.simulator.get_mutable_context())

    def _scene_graph_context(self):
        return self._model.scene_graph.GetMyMutableContextFromRoot(self.simulator.get_mutable_context())

    def freeze_resting_objects(self, on: bool) -> None:
        """Freeze objects at rest away from the hand from now on (`resting_objects`), or
        wake them all and stop."""
        with self.lock:
            if on and self._resting is None:
                self._resting = RestingObjects(self._model, self._scene_graph_context(), self.names, self._hull_vertices)
            elif not on and self._resting is not None:
                self._resting.wake_all()
                self._resting = None

    def checkpoint(self) -> "WorldCheckpoint":
        """Everything the world's next steps depend on, to run them again from here
        (`rewind`): the Drake context (object states; SceneGraph's collision filters), the
        hand's hold pose and motion, the finger servo, the removed, frozen and out-of-play objects."""
        with self.lock:
            resting = self._resting
            return WorldCheckpoint(self.simulator.get_context().Clone(),
                                   {k: copy.copy(getattr(self, k)) for k in ("_hold", "_motion", "_removed")},
                                   copy.copy(vars(self._fingers)),
                                   resting, resting.saved() if resting is not None else None,
                                   self._out_of_play.saved())

    def rewind(self, checkpoint: "WorldCheckpoint") -> None:
        """Back to the state `checkpoint` saved, simulated time included."""
        with self.lock:
            self.simulator.get_mutable_context().SetTimeStateAndParametersFrom(checkpoint.context)
            self.simulator.Initialize()  # Drake's simulator refuses a context whose time went back otherwise
            for k, v in checkpoint.world.items():
                setattr(self, k, copy.copy(v))
            vars(self._fingers).update(copy.copy(checkpoint.fingers))
            if self._model.transmission_lock is not None:
                self._model.transmission_lock.sync_gains(self.simulator.get_context())
            self._resting = checkpoint.resting
            if self._resting is not None:
                self._resting.restore(checkpoint.resting_state, self._scene_graph_context())
            self._out_of_play.restore(checkpoint.out_of_play, self._scene_graph_context())

    def asleep_objects(self) -> list:
        """Names of the objects frozen now (none unless freezing is on)."""
        with self.lock:
            return self._resting.asleep() if self._resting is not None else []

    # -- time ---------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        with self.lock:
            return self.simulator.get_context().get_time()

    def advance(self, duration_s: float) -> None:
        """Simulate `duration_s` more seconds (arm motion, fingers, objects)."""
        with self.lock:
            self._advance_locked(duration_s)

    def needs_stepping(self) -> bool:
        """True while something moves: an arm motion runs, the fingers move or build up
        their grip, or a body is faster than 1 mm/s (a RealTimeRunner idles otherwise)."""
        with self.lock:
            if self._motion is not None and not self._motion.done.is_set():
                return True
            if self.fingers_busy():
                return True
            v = self._model.plant.GetVelocities(self._plant_context())
            return bool(np.abs(v).max(initial=0.0) > 1e-3)

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
            force_n = float(np.linalg.norm(self.hand_contact_force_n()))
            if force_n - m.force_start_n > self.settings.max_contact_force_n:
                X_now = self.tcp_pose()
                self._hold = X_now
                done = float(np.linalg.norm(X_now[:3, 3] - m.X_start[:3, 3]))
                m.finish(False, f"stopped by contact after {done:.3f} of {m.length_m:.3f} m: "
                                f"the force on the hand rose from {m.force_start_n:.0f} to {force_n:.0f} N, by more "
                                f"than the {self.settings.max_contact_force_n:.0f} N limit", X_now, by_contact=True)
            elif m.finished(self.time_s):
                self._hold = m.X_goal
                m.finish(True, f"reached the target ({m.length_m:.3f} m in {m.duration_s:.2f} s)")
        else:
            self._set_hand_state(self._hold, np.zeros(3), np.zeros(3))
            self.simulator.AdvanceTo(t + dt)
        self._out_of_play.after_step(self._plant_context())
        if self._resting is not None:
            self._resting.after_step(self._plant_context(), self.time_s)
        self._fingers.update_stall()

    def _set_hand_state(self, X_task_tcp, v_task, w_task):
        """The stand-in: put the hand's floating body where the TCP reference says."""
        plant, pc = self._model.plant, self._plant_context()
        X_tcp_mount = self._X_tcp_mount
        X_mount = X_task_tcp @ X_tcp_mount
        p_tcp_mount_W = X_task_tcp[:3, :3] @ X_tcp_mount[:3, 3]
        plant.SetFreeBodyPose(pc, self._model.mount_body, _rigid(X_mount))
        plant.SetFreeBodySpatialVelocity(pc, self._model.mount_body, SpatialVelocity(
            np.asarray(w_task, float), np.asarray(v_task, float) + _cross(w_task, p_tcp_mount_W)))

    # -- arm ----------------------------------------------------------------------

    def tcp_pose(self) -> np.ndarray:
        """Current X_task_tcp (4x4)."""
        with self.lock:
            pc = self._plant_context()
            return self._model.plant.CalcRelativeTransform(pc, self._model.plant.world_frame(),
                                                      self._model.hand.tcp_frame).GetAsMatrix4()

    def check_reachable(self, X_task_tcp) -> tuple:
        """(reachable, message): the stand-in reaches a TCP pose inside its workspace box
        and not below the table top."""
        return check_reachable(X_task_tcp, self.settings)

    def start_move(self, X_task_tcp, speed_mps: float) -> Motion:
        """Start a straight-line TCP motion from the current reference; returns the Motion
        (finished later by stepping). An unreachable target or a bad speed gives a Motion
        that is already done with success False."""
        ok, msg = self.check_reachable(X_task_tcp)
        if ok and not (np.isfinite(speed_mps) and speed_mps > 0):
            ok, msg = False, f"speed_mps {speed_mps}: must be > 0"
        with self.lock:
            if self._motion is not None and not self._motion.done.is_set():
                ok, msg = False, "another motion is running"
            speed = min(float(speed_mps), self.settings.max_speed_mps) if ok else 1.0
            m = Motion(self._hold, np.asarray(X_task_tcp, float) if ok else self._hold, self.time_s,
                       speed, self.settings.max_angular_speed_rad_s)
            if not ok:
                m.finish(False, msg)
            else:
                m.force_start_n = float(np.linalg.norm(self.hand_contact_force_n()))
                self._motion = m
            return m

    def stop_motion(self, why: str = "stopped on request") -> bool:
        """Halt the running motion at once where the reference is now (an arm's protective
        stop); it ends with success False and `why` as its message. False if none ran."""
        with self.lock:
            m = self._motion
            if m is None or m.done.is_set():
                return False
            self._hold = m.reference(self.time_s)[0]
            m.finish(False, why, self._hold)
            return True

    def move_tcp(self, X_task_tcp, speed_mps: float, timeout_s: float = 30.0) -> tuple:
        """Move along a straight line, stepping the simulation here; (success, message)."""
        return self.travel(X_task_tcp, speed_mps, timeout_s).result

    def travel(self, X_task_tcp, speed_mps: float, timeout_s: float = 30.0) -> Motion:
        """`move_tcp`, returning the finished Motion (how far short, whether by contact)."""
        m = self.start_move(X_task_tcp, speed_mps)
        with self.lock:
            t_end = self.time_s + timeout_s
            while not m.done.is_set() and self.time_s < t_end:
                self._advance_locked(0.01)
        if not m.done.is_set():
            with self.lock:
                self._hold = self.tcp_pose()
                m.finish(False, f"did not finish within {timeout_s} s of simulated time", self._hold)
        return m

    def hand_contact_force_n(self) -> np.ndarray:
        """Net contact force [N] on the hand from everything else (task frame): a wrist
        force sensor's reading, without the hand's own weight."""
        with self.lock:
            total = np.zeros(3)
            for _, _, force in hand_contacts(self._model, self._plant_context()):
                total += force
            return total

    def hand_touches(self) -> list:
        """What touches the hand now: (hand link, other body, force on the hand [3] N) per
        contact, by body name (an object's body is named as the object)."""
        with self.lock:
            return hand_touches(self._model, self._plant_context())

    # -- fingers ------------------------------------------------------------------

    def command_fingers(self, target_width_m: float, speed_mps: float, force_n: float) -> None:
        """Move the fingers towards an opening [m] at a speed [m/s of opening], squeezing at
        most `force_n` [N] (a new target restarts the stall detection)."""
        with self.lock:
            self._fingers.command(target_width_m, speed_mps, force_n)

    def fingers_commanded(self) -> bool:
        """True while a finger command runs (not stopped by `hold_fingers`)."""
        with self.lock:
            return self._fingers.commanded()

    def hold_fingers(self) -> None:
        """Stop the fingers where they are (the 2F-85's rGTO = 0; its drive self-locks)."""
        with self.lock:
            self._fingers.hold()

    def fingers_locked(self) -> bool:
        """True while a self-locking transmission holds the fingers (stopped on something;
        SimSettings.drive "self_locking"); never for a back-drivable drive."""
        with self.lock:
            return self._fingers.locked()

    def driver_angle_rad(self) -> float:
        with self.lock:
            return self._fingers.driver_angle_rad()

    def finger_width_m(self) -> float:
        with self.lock:
            return self._fingers.width_m()

    def finger_status(self) -> tuple:
        """(width_m, state) with state 'moving', 'at_target' or 'blocked' (stopped short
        of the target: on an object, or with the fingers touching each other)."""
        with self.lock:
            return self._fingers.status()

    def fingers_busy(self) -> bool:
        """True while the fingers move or the servo is still building up its grip."""
        with self.lock:
            return self._fingers.busy()

    def grip_force_n(self) -> tuple:
        """(left, right) [N]: how hard each finger presses on what it touches, along the
        TCP's closing axis (ground truth: the grip force)."""
        with self.lock:
            return finger_squeeze_n(self._model, self._plant_context(), self.tcp_pose()[:3, 1])

    def parallel_grip(self) -> GripVerdict:
        """Held or not, for a parallel-jaw hand (the Panda): from the finger positions and
        the ground truth (`parallel_grip`)."""
        with self.lock:
            return judge_parallel_grip(self._fingers.width_m(), self.object_states())

    # -- objects ------------------------------------------------------------------

    def _body(self, name):
        if name not in self.names or name in self._removed:
            raise KeyError(f"no object named {name!r}; objects: {', '.join(self.object_names())}")
        return self._model.object_bodies[self.names.index(name)]

    def object_names(self) -> list:
        with self.lock:
            return [n for n in self.names if n not in self._removed]

    def object_states(self) -> list:
        """Ground truth (ObjectState) for every object still in the scene (removed ones are left out)."""
        with self.lock:
            return object_states(self._model, self._plant_context(), self.names, self._removed,
                                 self._hull_vertices)

    def object_meshes(self) -> dict:
        """{name: (visual trimesh, X_task_mesh 4x4)} of the objects still in the scene, as
        the camera renders them now."""
        with self.lock:
            names = self.object_names()
            posed = self._meshes.posed(self._plant_context(), names)
        return dict(zip(names, posed[1:1 + len(names)]))  # after the table, before the hand

    def set_object_mass(self, name: str, mass_kg: float) -> None:
        """Scale an object's mass (and inertia) to `mass_kg`; name '' = every object."""
        if not (np.isfinite(mass_kg) and mass_kg > 0):
            raise ValueError(f"mass_kg {mass_kg}: must be > 0")
        with self.lock:
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
        a successful grasp): out of the physics, held far out of view (`out_of_play`; it
        was once dropped onto a shelf there, which threw light boxes off it). (Locking the
        body instead made a later SAP step crash in libdrake.)"""
        with self.lock:
            self._body(name)  # one clear error for a name that is not there
            pc = self._plant_context()
            self._out_of_play.take_out(pc, name, "removed")
            if self._resting is not None:
                self._resting.moved(pc, name)
            self._removed.add(name)

    # -- camera -------------------------------------------------------------------

    def camera_pose(self) -> np.ndarray:
        return camera_pose(self.settings.camera)

    def intrinsics(self):
        """gravgrasp_detector.perception.tsdf.CameraIntrinsics of the camera (what TSDFVolume.integrate takes)."""
        return camera_intrinsics(self.settings.camera)

    def render_depth(self) -> tuple:
        """(depth float32 HxW [m], 0 = no return; CameraIntrinsics; T_task_camera 4x4) of
        the table, the objects and the hand as they are now."""
        with self.lock:
            posed = self._meshes.posed(self._plant_context(), self.object_names())
        return render_depth(self.settings.camera, posed)


def _return_freed_memory():
    """Hand freed heap pages back to the OS (glibc malloc_trim; elsewhere nothing). A
    scene is ~15 MB of small allocations, and the sim node reloads it from whichever
    executor thread serves load_scene: each thread's malloc arena kept its freed scene,
    +75 MB over 4 reloads in a 10 min soak, until trimmed."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _rigid(X):
    return RigidTransform(np.asarray(X, float))
