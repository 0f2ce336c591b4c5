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
rotation along the geodesic), like a MuJoCo mocap body. This is an infinitely stiff
position-controlled arm: nothing sags under a heavy object, and there are no stand-in
gains to tune against SAP (a stiff explicit PD on the floating base needs gains near the
explicit-stability limit at dt = 2 ms and still sagged degrees under a 1.5 kg object in a
side grasp). Gravity is off for the hand only (the arm carries it). The fingers stay fully
dynamic and the contacts are SAP's. The net contact force on the hand links (what a wrist
force/torque sensor reads) stops a motion when it exceeds `max_contact_force_n`.

Fingers: `physics.actuators.FingerServoSystem` (a LeafSystem) is the 2F-85's motor: a position servo on the
driver joint whose reference moves at the commanded speed and whose torque is clipped at
the value that squeezes the commanded force (grasp_simulation's calibration). Blocked by
an object, the reference runs on to the target and the torque saturates: a force-limited
grip, as the real gripper does. Width is reported from the driver angle through the
free-closing calibration (`DRIVER_ANGLE_RAD` -> `PAD_GAP_M`), as the real gripper reports
its motor position, not the pad gap.

Depth: Open3D ray casting of the posed visual meshes (table, objects, hand), so the hand
shows up when it is in view, as on a real cell.

Thread safety: every public method takes one lock (`SimWorld.lock`), so a `RealTimeRunner` thread can
step the world while other threads command it and read from it.
"""

from __future__ import annotations

import gc
import pathlib
import threading
from dataclasses import dataclass

import numpy as np
import trimesh
from pydrake.geometry import Box, Capsule, Convex, Cylinder, Mesh, Sphere
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.tree import RotationalInertia, SpatialInertia
from pydrake.systems.analysis import Simulator

from gravgrasp_detector.tsdf import CameraIntrinsics

from ..physics import hand_model
from ..physics.actuators import FingerServoSystem, driver_torque_nm
from ..physics.objects import load_mesh_object, random_procedural_objects
from ..physics.scenes import TABLE_HEIGHT_M, VOLUME_SIZE_M, SceneSettings, arrange
from .config import BARE_MESH_DENSITY_KG_M3, R_TOP_DOWN, SceneConfig, WorldSettings, pose
from .diagram import PARKING_SHELF_M, build_world_diagram
from .finger_calibration import GAP_PER_DRIVER_RAD_M, driver_angle_for_width, width_from_driver_angle
from .motion import Motion

# The hand's floating body weighs this much in the simulation. Its state is reset every
# step, but within a step SAP moves it under the contact forces: at its real 0.8 kg a held
# 0.3 kg object dragged it down 12 um per step, which the reset turned into a 6 mm/s slip
# of the object in the grasp. At 1000 kg the same load gives 6 um/s.
STAND_IN_MASS_KG = 1000.0


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


class SimWorld:
    """A Drake world stepped by the caller (`advance`) or by a `RealTimeRunner` thread.

    Every public method takes `lock` (re-entrant); hold it to make several calls one
    atomic step, as the runner does."""

    def __init__(self, scene_config: SceneConfig | None = None, settings: WorldSettings | None = None):
        self.settings = settings or WorldSettings()
        self.settings.validate()
        self.lock = threading.RLock()
        self._finger_command = None
        self._stall_since_s = self._blocked_angle = None
        self._motion = None
        self.scenes_loaded = 0  # how many scenes were loaded (reset)
        self.reset(scene_config or SceneConfig())

    # -- scene ------------------------------------------------------------------------

    def reset(self, scene_config: SceneConfig) -> list:
        """Build the world for `scene_config` (drawing, arranging and settling objects);
        the hand goes home, open. Returns the object names. On an error the current
        world stays."""
        scene_config.validate()
        named, poses = self._draw_scene(scene_config)
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
            self._meshes = None  # visual meshes for the camera, loaded at the first frame
            self._make_simulator()
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
            self._finger_command = None
            self._stall_since_s = self._blocked_angle = None
            self._model.finger_servo.set_command(self._servo_context(), 0.0, 1.0,
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

    def _make_simulator(self):
        self.simulator = Simulator(self._model.diagram)

    def _plant_context(self):
        return self._model.plant.GetMyMutableContextFromRoot(self.simulator.get_mutable_context())

    def _servo_context(self):
        return self._model.finger_servo.GetMyMutableContextFromRoot(self.simulator.get_mutable_context())

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
        with self.lock:
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
        with self.lock:
            m = self._motion
            if m is None or m.done.is_set():
                return False
            self._hold = m.reference(self.time_s)[0]
            m.finish(False, "stopped on request")
            return True

    def move_tcp(self, X_task_tcp, speed_mps: float, timeout_s: float = 30.0) -> tuple:
        """Move along a straight line, stepping the simulation here; (success, message)."""
        m = self.start_move(X_task_tcp, speed_mps)
        with self.lock:
            t_end = self.time_s + timeout_s
            while not m.done.is_set() and self.time_s < t_end:
                self._advance_locked(0.01)
        if not m.done.is_set():
            with self.lock:
                self._hold = self.tcp_pose()
                m.finish(False, f"did not finish within {timeout_s} s of simulated time")
        return m.result

    def hand_contact_force_n(self) -> np.ndarray:
        """Net contact force [N] on the hand from everything else (task frame): a wrist
        force sensor's reading, without the hand's own weight."""
        with self.lock:
            total = np.zeros(3)
            for _, _, force in self._hand_contacts():
                total += force
            return total

    def _hand_contacts(self):
        """(hand geometry id value, other geometry id value, force on the hand [3] N)
        per contact between the hand and something else."""
        plant, pc = self._model.plant, self._plant_context()
        results = plant.get_contact_results_output_port().Eval(pc)
        hand_g = self._model.hand_geometries
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
        hand_bodies = self._model.hand_bodies
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
        plant, pc = self._model.plant, self._plant_context()
        results = plant.get_contact_results_output_port().Eval(pc)
        hand_g = self._model.hand_geometries
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
        with self.lock:
            cmd = self._finger_command
            if cmd is None or (cmd.target_width_m, cmd.speed_mps, cmd.force_n) != (target_width_m, speed_mps, force_n):
                self._finger_command = FingerCommand(target_width_m, speed_mps, force_n, self.time_s)
                self._stall_since_s = self._blocked_angle = None
                ctx = self._servo_context()
                if cmd is None:  # first command: start the reference where the fingers are
                    self._model.finger_servo.set_reference(ctx, self.driver_angle_rad())
                self._model.finger_servo.set_command(
                    ctx, driver_angle_for_width(target_width_m),
                    max(speed_mps, 1e-3) / GAP_PER_DRIVER_RAD_M, driver_torque_nm(force_n))

    def fingers_commanded(self) -> bool:
        """True while a finger command runs (not stopped by `hold_fingers`)."""
        with self.lock:
            return self._finger_command is not None and not self._finger_command.held

    def hold_fingers(self) -> None:
        """Stop the fingers where they are (the 2F-85's rGTO = 0; its drive self-locks)."""
        with self.lock:
            if self._finger_command is None:
                return
            angle = self.driver_angle_rad()
            ctx = self._servo_context()
            _, rate, torque = self._model.finger_servo.command(ctx)
            self._model.finger_servo.set_reference(ctx, angle)
            self._model.finger_servo.set_command(ctx, angle, rate, torque)
            self._finger_command = FingerCommand(width_from_driver_angle(angle), self._finger_command.speed_mps,
                                                 self._finger_command.force_n, self.time_s, held=True)

    def driver_angle_rad(self) -> float:
        with self.lock:
            return self._model.hand.driver_angle_rad(self._model.plant, self._plant_context())

    def finger_width_m(self) -> float:
        return width_from_driver_angle(self.driver_angle_rad())

    def _driver_rate(self):
        pc = self._plant_context()
        iv = self._model.hand.driver_joints[0].velocity_start()
        return float(self._model.plant.GetVelocities(pc)[iv])

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
        with self.lock:
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
        _, _, limit = self._model.finger_servo.command(ctx)
        q = self.driver_angle_rad()
        tau = FingerServoSystem.KP_NM_PER_RAD * (self._model.finger_servo.reference(ctx) - q)
        return tau * (target_angle - q) > 0 and abs(tau) >= 0.9 * limit

    def fingers_busy(self) -> bool:
        """True while the fingers move or the servo is still building up its grip."""
        with self.lock:
            if self._finger_command is None:
                return False
            target, _, _ = self._model.finger_servo.command(self._servo_context())
            ref = self._model.finger_servo.reference(self._servo_context())
            return abs(ref - target) > 1e-9 or self.finger_status()[1] == "moving"

    # -- objects ------------------------------------------------------------------

    def _object_poses(self):
        pc = self._plant_context()
        return {n: self._model.plant.EvalBodyPoseInWorld(pc, b).GetAsMatrix4()
                for n, b in zip(self.names, self._model.object_bodies)}

    def _body(self, name):
        if name not in self.names or name in self._removed:
            raise KeyError(f"no object named {name!r}; objects: {', '.join(self.object_names())}")
        return self._model.object_bodies[self.names.index(name)]

    def object_names(self) -> list:
        with self.lock:
            return [n for n in self.names if n not in self._removed]

    def object_states(self) -> list:
        """Ground truth for every object still in the scene (removed ones are left out)."""
        with self.lock:
            poses = self._object_poses()
            touching = {}
            left = {g for g, l in self._model.hand_link_of.items() if l.startswith("left_")}
            right = {g for g, l in self._model.hand_link_of.items() if l.startswith("right_")}
            geom_owner = {}
            for n, b in zip(self.names, self._model.object_bodies):
                for g in self._model.plant.GetCollisionGeometriesForBody(b):
                    geom_owner[g.get_value()] = n
            inner = set(hand_model.PALM_LINKS) | set(hand_model.PROXIMAL_LINKS)  # as grasp_simulation's modes
            wrapped = set()
            for h, other in self._hand_contact_pairs():
                n = geom_owner.get(other)
                if n is not None:
                    touching.setdefault(n, set()).add("left" if h in left else "right" if h in right else "palm")
                    if self._model.hand_link_of.get(h) in inner:
                        wrapped.add(n)
            pc = self._plant_context()
            out = []
            for n, b in zip(self.names, self._model.object_bodies):
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
        a successful grasp): it is put down on a shelf far out of view, 0.5 m from the
        previous one. (Locking the body instead made a later SAP step crash in libdrake.)"""
        with self.lock:
            body = self._body(name)
            pc = self._plant_context()
            k = len(self._removed)
            x, y, z = PARKING_SHELF_M
            self._model.plant.SetFreeBodyPose(pc, body, _rigid(pose(p=(x + 0.5 * k, y, z + 0.2))))
            self._model.plant.SetFreeBodySpatialVelocity(pc, body, _zero_velocity())
            self._removed.add(name)

    # -- camera -------------------------------------------------------------------

    def camera_pose(self) -> np.ndarray:
        # depth_rendering loads open3d (ray casting): only when the camera is used.
        from ..physics.depth_rendering import look_at

        c = self.settings.camera
        return look_at(c.position_m, c.target_m)

    def intrinsics(self):
        """gravgrasp_detector.tsdf.CameraIntrinsics of the camera (what TSDFVolume.integrate takes)."""
        c = self.settings.camera
        return CameraIntrinsics(c.width, c.height, c.focal_px, c.focal_px, (c.width - 1) / 2, (c.height - 1) / 2)

    def render_depth(self) -> tuple:
        """(depth float32 HxW [m], 0 = no return; CameraIntrinsics; T_task_camera 4x4) of
        the table, the objects and the hand as they are now."""
        # open3d (ray casting) is loaded at the first frame only: most worlds never render.
        from ..physics.depth_rendering import DepthRenderer

        with self.lock:
            posed = self._posed_visual_meshes()
        T = self.camera_pose()
        k = self.intrinsics()
        depth = DepthRenderer(posed).render(k, T, self.settings.camera.max_depth_m)
        return depth, k, T

    def _posed_visual_meshes(self):
        """(trimesh, X_task_mesh) for the table, every object in the scene and every hand link."""
        plant, pc = self._model.plant, self._plant_context()
        if self._meshes is None:
            self._meshes = self._visual_meshes()
        cache = self._meshes
        out = [(cache["table"], np.eye(4))]
        for n, b in zip(self.names, self._model.object_bodies):
            if n not in self._removed:
                out.append((cache["objects"][n], plant.EvalBodyPoseInWorld(pc, b).GetAsMatrix4()))
        for body, mesh, X_BG in cache["hand"]:
            out.append((mesh, plant.EvalBodyPoseInWorld(pc, body).GetAsMatrix4() @ X_BG))
        return out

    def _visual_meshes(self):
        table = trimesh.creation.box((1.0, 1.0, 0.05))
        table.apply_translation([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M - 0.025])
        objects = {}
        for n in self.names:
            spec = self._specs[n]
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
    return RigidTransform(np.asarray(X, float))


def _zero_velocity():
    return SpatialVelocity(np.zeros(3), np.zeros(3))
