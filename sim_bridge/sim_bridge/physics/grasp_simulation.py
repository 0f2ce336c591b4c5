"""Gravity-free grasp simulation of the 2F-85 on one free object (paper Sec. III).

`evaluate_grasp` places the open hand at a pose relative to the object, closes it with
the grip force, lets the object settle (physics picks power or precision), classifies
the mode from which hand links touch, then from that same settled state ramps a force
at the object's COM along ±x, ±y, ±z of the TCP frame and records the force [N] at
which the object leaves the hand (see disturbance_rejection).

The hand's flange is welded at the world origin; the object is a free body. Everything
is one Drake diagram (plant + scene graph + `GripForceController` + the ramp, and with
the self-locking drive its `TransmissionLock`, engaged once the hand has settled).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from . import hand_model
from .hand_model import WRAP_MIN_RAD
from .actuators import GripForceController, driver_torque_nm
from .contact import SimSettings, proximity_properties
from .transmission import add_transmission_lock
from .disturbance_rejection import DIRECTIONS_TCP, ForceRampDisturbance, measure_departure_force
from .objects import ObjectSpec, procedural_object

MODES = ("power", "precision", "none")

LOCKED_HOLD_S = 0.3  # squeeze calibration: how long the locked drive holds before reading


@dataclass
class GraspOutcome:
    grasped: bool
    mode: str  # "power" | "precision" | "none"
    X_object_tcp_settled: np.ndarray  # 4x4, TCP pose in the object frame after settling
    scores_n: np.ndarray  # (6,) +x, -x, +y, -y, +z, -z of the TCP frame; 0 if not grasped
    contact_links: tuple = ()
    num_contacts: int = 0  # hand-object contact patches (hydroelastic) or points
    finger_joint_angles: dict = field(default_factory=dict)
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    departed: np.ndarray = field(default_factory=lambda: np.zeros(6, bool))  # False = capped
    reason: str = ""  # why not grasped
    wrap_rad: float = 0.0  # how far both distal links wrapped past their stop (wrap_angle_rad)

    @property
    def min_score_n(self) -> float:
        return float(self.scores_n.min())


class GraspSimulator:
    """One diagram for one object; evaluate many hand poses on it (datagen reuses it)."""

    def __init__(self, obj: ObjectSpec, settings: SimSettings | None = None, mass_kg=None):
        settings = settings or SimSettings()
        settings.validate()
        self.settings = settings
        builder = DiagramBuilder()
        cfg = MultibodyPlantConfig(
            time_step=settings.time_step_s,
            discrete_contact_approximation="sap",
            contact_model="hydroelastic_with_fallback" if settings.contact_model == "hydroelastic" else "point",
        )
        plant, scene_graph = AddMultibodyPlant(cfg, builder)
        props = proximity_properties(settings)
        self.hand = hand_model.add_hand(plant, scene_graph, props,
                                        pad_contact_points=settings.contact_model == "point")
        self.object_body = obj.add_to_plant(plant, mass_kg=mass_kg, proximity_properties=props)
        self.object_instance = self.object_body.model_instance()
        self.object = obj if mass_kg is None else obj.with_mass(mass_kg)
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
        plant.Finalize()
        ctrl = builder.AddSystem(GripForceController(
            plant, self.hand, driver_torque_nm(settings.grip_force_n), settings.closing_speed_rad_s))
        builder.Connect(plant.get_state_output_port(), ctrl.get_input_port())
        builder.Connect(ctrl.get_output_port(), plant.get_actuation_input_port())
        self.ramp = builder.AddSystem(ForceRampDisturbance(self.object_body.index(), self.object.com_m))
        builder.Connect(self.ramp.get_output_port(), plant.get_applied_spatial_force_input_port())
        # The self-locking drive engages once the hand has settled on the object (evaluate).
        self.lock = (add_transmission_lock(
            builder, plant, self.hand, settings.time_step_s, driver_torque_nm(settings.grip_force_n),
            stiffness_nm_per_rad=settings.lock_stiffness_nm_per_rad,
            damping_nm_s_per_rad=settings.lock_damping_nm_s_per_rad)
            if settings.drive == "self_locking" else None)
        self.diagram = builder.Build()
        self.plant, self.scene_graph = plant, scene_graph
        self.simulator = Simulator(self.diagram)
        self._default = self.diagram.CreateDefaultContext()
        pc = plant.GetMyContextFromRoot(self._default)
        self.X_W_tcp = plant.CalcRelativeTransform(pc, plant.world_frame(), self.hand.tcp_frame)
        # Geometry ids by value, read after Finalize (hand_model.Hand.geometry_links can
        # hold stale ids; see Hand.collision_geometry_links).
        self._object_geoms = {int(g.get_value()) for g in plant.GetCollisionGeometriesForBody(self.object_body)}
        self.hand_link_of = self.hand.collision_geometry_links(plant)
        self.hand.geometry_links = {g: plant.get_body(b).name() for b in plant.GetBodyIndices(self.hand.model_instance)
                                    for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))}

    # --- helpers -------------------------------------------------------------------
    def contact_links(self, root):
        """Names of the hand links touching the object."""
        return self._contact_summary(root)[0]

    def _contact_summary(self, root):
        """(names of the hand links touching the object, number of hand-object contacts:
        hydroelastic patches or contact points)."""
        pc = self.plant.GetMyContextFromRoot(root)
        results = self.plant.get_contact_results_output_port().Eval(pc)
        links, n = set(), 0
        obj_idx = self.object_body.index()
        for i in range(results.num_hydroelastic_contacts()):
            s = results.hydroelastic_contact_info(i).contact_surface()
            m_, n_ = int(s.id_M().get_value()), int(s.id_N().get_value())
            for a, b in ((m_, n_), (n_, m_)):
                if a in self._object_geoms and b in self.hand_link_of:
                    links.add(self.hand_link_of[b])
                    n += 1
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            for a, b in ((info.bodyA_index(), info.bodyB_index()), (info.bodyB_index(), info.bodyA_index())):
                if a == obj_idx and b != obj_idx:
                    links.add(self.plant.get_body(b).name())
                    n += 1
        return links, n

    def _initial_collision(self, root) -> bool:
        sg_ctx = self.scene_graph.GetMyContextFromRoot(root)
        q = self.scene_graph.get_query_output_port().Eval(sg_ctx)
        for p in q.ComputePointPairPenetration():
            if (int(p.id_A.get_value()) in self._object_geoms) != (int(p.id_B.get_value()) in self._object_geoms):
                return True
        return False

    def collides(self, X_object_tcp: np.ndarray) -> bool:
        """Whether the open hand touches the object at `X_object_tcp` (no simulation)."""
        root = self.simulator.get_mutable_context()
        root.SetTimeStateAndParametersFrom(self._default)
        X_W_O = self.X_W_tcp @ RigidTransform(np.asarray(X_object_tcp, float)).inverse()
        self.plant.SetFreeBodyPose(self.plant.GetMyContextFromRoot(root), self.object_body, X_W_O)
        return self._initial_collision(root)

    def squeeze_force_n(self, root) -> float:
        """Force [N] the right finger presses on the object along the closing axis."""
        pc = self.plant.GetMyContextFromRoot(root)
        results = self.plant.get_contact_results_output_port().Eval(pc)
        y_W = self.X_W_tcp.rotation().matrix()[:, 1]
        total = 0.0
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            s = info.contact_surface()
            for gid in (s.id_M(), s.id_N()):
                if self.hand_link_of.get(int(gid.get_value()), "").startswith("right_"):
                    total += abs(float(info.F_Ac_W().translational() @ y_W))
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            for b in (info.bodyA_index(), info.bodyB_index()):
                if self.plant.get_body(b).name().startswith("right_"):
                    total += abs(float(info.contact_force() @ y_W))
        return total

    def finger_joint_angles(self, root) -> dict:
        pc = self.plant.GetMyContextFromRoot(root)
        out = {}
        for side in ("left", "right"):
            for j in ("driver", "spring_link", "follower", "coupler"):
                joint = self.plant.GetJointByName(f"{side}_{j}_joint", self.hand.model_instance)
                out[f"{side}_{j}"] = float(joint.get_angle(pc))
        return out

    def X_object_tcp(self, root) -> np.ndarray:
        pc = self.plant.GetMyContextFromRoot(root)
        X_W_O = self.plant.EvalBodyPoseInWorld(pc, self.object_body)
        return (X_W_O.inverse() @ self.X_W_tcp).GetAsMatrix4()

    # --- the two phases ----------------------------------------------------------
    def close(self, X_object_tcp: np.ndarray):
        """Reset, place the object, close the hand until everything settles.
        Returns (root context, reason) where reason is '' on a clean run."""
        s = self.settings
        root = self.simulator.get_mutable_context()
        root.SetTimeStateAndParametersFrom(self._default)
        if self.lock is not None:
            self.lock.release(root)
        pc = self.plant.GetMyContextFromRoot(root)
        X_W_O = self.X_W_tcp @ RigidTransform(np.asarray(X_object_tcp, float)).inverse()
        self.plant.SetFreeBodyPose(pc, self.object_body, X_W_O)
        if self._initial_collision(root):
            return root, "hand collides with the object at the initial pose"
        self.ramp.set_ramp(self.ramp.GetMyContextFromRoot(root), np.zeros(3), 1e9, 0.0)
        self.simulator.Initialize()
        iq = self.hand.driver_joints[0].position_start()
        calm, t = 0, 0.0
        chunk = max(0.02, 5 * s.time_step_s)
        X_prev, q_prev = X_W_O, self.plant.GetPositions(pc)[iq]
        while t < s.max_close_time_s:
            t += chunk
            self.simulator.AdvanceTo(t)
            x = self.plant.GetPositionsAndVelocities(pc)
            # Settled = the object and the fingers do not *move*: mean speeds over the
            # chunk from the displacement, not the instantaneous velocities. Wedged
            # between the palm and the pads, SAP's velocities chatter step to step
            # (measured: object 41 mm/s and driver 2.9 rad/s in the state while the
            # object moved < 0.1 mm and the driver 0.008 rad in 2.8 s), which made
            # such grasps "did not settle".
            X_now = self.plant.EvalBodyPoseInWorld(pc, self.object_body)
            dX = X_prev.inverse() @ X_now
            v_lin = np.linalg.norm(X_now.translation() - X_prev.translation()) / chunk
            v_rot = abs(dX.rotation().ToAngleAxis().angle()) / chunk
            # finger speed at the pads ~ driver rate x 0.1 m lever
            v_fing = abs(x[iq] - q_prev) / chunk * 0.1
            X_prev, q_prev = X_now, x[iq]
            speed = max(v_lin, v_rot * 0.03, v_fing)
            calm = calm + 1 if speed < s.settle_speed_m_s else 0
            if calm >= 3 and t > 0.1:
                return root, ""
            # Closed on nothing while the object drifts off (gravity-free, nothing stops
            # it): no need to wait for it.
            if (x[iq] > hand_model.DRIVER_CLOSED_RAD - 0.06 and v_fing < s.settle_speed_m_s
                    and not self.contact_links(root)):
                moved = self.plant.EvalBodyPoseInWorld(pc, self.object_body).translation() - X_W_O.translation()
                if np.linalg.norm(moved) > 0.005:
                    return root, "object pushed out of the hand"
                return root, "hand closed on nothing (no contact)"
        return root, "did not settle"

    def evaluate(self, X_object_tcp: np.ndarray) -> GraspOutcome:
        s = self.settings
        wall0 = time.perf_counter()
        root, reason = self.close(X_object_tcp)
        links, n_contacts = (self._contact_summary(root) if not reason.startswith("hand collides")
                             else (set(), 0))
        grasped = held_between_fingers(links) and not reason
        if grasped and self.lock is not None:
            self.lock.engage(root)  # the fingers have stalled on the object: the screw holds
        angles = self.finger_joint_angles(root)
        wrap = wrap_angle_rad(angles)
        if grasped:
            mode = classify_mode(links, wrap)
        else:
            mode = "none"
            if not reason:
                reason = "object not held between both fingers" if links else "no contact"
        X_ot = self.X_object_tcp(root)
        scores = np.zeros(6)
        departed = np.zeros(6, bool)
        sim_time = root.get_time()
        if grasped:
            settled = root.Clone()
            R_W_tcp = self.X_W_tcp.rotation().matrix()
            for i, d_tcp in enumerate(DIRECTIONS_TCP):
                root.SetTimeStateAndParametersFrom(settled)
                scores[i], departed[i], t = measure_departure_force(
                    self.simulator, self.plant, self.object_instance, self.ramp,
                    R_W_tcp @ d_tcp, s.force_ramp_rate_n_s, s.max_force_n,
                    s.departure_travel_m, s.resistance_window_s)
                sim_time += t
            root.SetTimeStateAndParametersFrom(settled)
        return GraspOutcome(
            grasped=grasped, mode=mode, X_object_tcp_settled=X_ot, scores_n=scores,
            contact_links=tuple(sorted(links)), num_contacts=n_contacts, finger_joint_angles=angles,
            sim_time_s=sim_time, wall_time_s=time.perf_counter() - wall0,
            departed=departed, reason=reason, wrap_rad=wrap)


def held_between_fingers(contact_links) -> bool:
    """After a clean closing: the object touches a link of each finger."""
    return any(n.startswith("left_") for n in contact_links) and any(n.startswith("right_") for n in contact_links)


def wrap_angle_rad(finger_joint_angles: dict) -> float:
    """How far the distal links wrapped past their stop [rad], the smaller of the two
    fingers' (an envelope needs both): the coupler sits at 0 while the spring holds the pad
    parallel and turns negative as the distal link wraps."""
    return max(0.0, min(-finger_joint_angles.get("left_coupler", 0.0),
                        -finger_joint_angles.get("right_coupler", 0.0)))


def classify_mode(contact_links, wrap_rad: float) -> str:
    """A held grasp's mode: "power" when the object touches the palm or a proximal link
    and both distal links wrapped past their stop (>= WRAP_MIN_RAD), else "precision"."""
    inner = set(hand_model.PALM_LINKS) | set(hand_model.PROXIMAL_LINKS)
    return "power" if set(contact_links) & inner and wrap_rad >= WRAP_MIN_RAD else "precision"


def measure_squeeze_force_n(width_m: float = 0.05, settings: SimSettings | None = None) -> float:
    """Grip-force calibration: close on a free 0.5 kg box `width_m` wide (along y),
    centred between the pads, and return the settled squeeze force [N] (with the
    self-locking drive: locked, LOCKED_HOLD_S after settling)."""
    box = procedural_object("box", (0.03, width_m, 0.03), mass_kg=0.5)
    sim = GraspSimulator(box, settings)
    root, reason = sim.close(np.eye(4))
    if reason:
        raise RuntimeError(f"calibration grasp failed: {reason}")
    if sim.lock is not None:  # the squeeze the locked drive keeps, LOCKED_HOLD_S later
        sim.lock.engage(root)
        sim.simulator.AdvanceTo(root.get_time() + LOCKED_HOLD_S)
    return sim.squeeze_force_n(root)


def evaluate_grasp(obj: ObjectSpec, X_object_tcp: np.ndarray,
                   settings: SimSettings | None = None, mass_kg=None) -> GraspOutcome:
    """Close the hand on `obj` from TCP pose `X_object_tcp` (4x4, object frame), settle,
    classify the mode and score 6 force ramps. Builds a fresh diagram; use
    `GraspSimulator` to evaluate many poses on one object."""
    return GraspSimulator(obj, settings, mass_kg).evaluate(X_object_tcp)
