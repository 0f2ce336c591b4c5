"""How each hand's fingers are driven in a SimWorld (`fingers.Fingers` runs either): the
finger servo's joint coordinate against the reported opening, the servo's gain and the
joint damping, the effort that squeezes a force, and what counts as stalled.

- 2F-85: the driver joint [rad]; opening from the free-closing calibration
  (finger_calibration), effort from the squeeze calibration (physics.actuators).
- Panda: each finger's prismatic joint [m], opening = twice the joint (the coupler keeps
  the fingers centred); each joint pushes with the grip force, so the fingers squeeze
  an object with it. Closing aims 5 mm per finger beyond the closed limit, so the full
  force is reached on anything between the pads (the joint limit stops the fingers on
  nothing, at an opening of 0: the target, reached)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..physics import panda_hand
from ..physics.actuators import FingerServoSystem, driver_torque_nm
from .finger_calibration import GAP_PER_DRIVER_RAD_M, driver_angle_for_width, width_from_driver_angle


@dataclass(frozen=True)
class FingerDrive:
    joint_for_width: Callable  # commanded opening [m] -> servo target (joint units)
    width_at: Callable  # joint position -> reported opening [m]
    width_per_joint_m: float  # d(opening)/d(joint): converts a speed [m/s of opening] to a joint rate
    effort_for_force: Callable  # squeeze [N] -> effort limit per actuated joint
    kp: float  # servo gain (effort per joint unit)
    joint_damping: float  # implicit in SAP (a damping term in the servo would be explicit)
    stall_rate: float  # joint speed under which the fingers count as still
    block_release: float  # joint travel that ends a stop on an object (~2 mm of opening)
    reached: Callable  # (joint position, target opening [m]) -> at the target?
    open_joint: float  # where the fingers are open (the model's default)


def _2f85_reached(q, target_width_m) -> bool:
    return abs(q - driver_angle_for_width(target_width_m)) < 0.01


TWO_F85 = FingerDrive(
    joint_for_width=driver_angle_for_width, width_at=width_from_driver_angle,
    width_per_joint_m=GAP_PER_DRIVER_RAD_M, effort_for_force=driver_torque_nm,
    kp=FingerServoSystem.KP_NM_PER_RAD, joint_damping=0.3, stall_rate=0.05, block_release=0.02,
    reached=_2f85_reached, open_joint=0.0)

PANDA_CLOSE_BEYOND_M = 0.005  # per finger, past the closed limit: full force on anything


def _panda_joint(width_m) -> float:
    if width_m <= 0.0:
        return -PANDA_CLOSE_BEYOND_M
    return min(width_m, panda_hand.MAX_OPENING_M) / 2


def _panda_width(q) -> float:
    return min(max(2.0 * q, 0.0), panda_hand.MAX_OPENING_M)


def _panda_reached(q, target_width_m) -> bool:
    return abs(_panda_width(q) - min(max(target_width_m, 0.0), panda_hand.MAX_OPENING_M)) < 1e-3


PANDA = FingerDrive(
    joint_for_width=_panda_joint, width_at=_panda_width, width_per_joint_m=2.0,
    effort_for_force=float,
    # 40 N at 4 mm short of the reference; the fingers' 0.1 kg each then ring at
    # 320 rad/s, 0.63 rad per 2 ms step: well inside what the explicit servo takes.
    kp=1e4, joint_damping=60.0,  # about critical for 0.1 kg at kp
    stall_rate=0.0025, block_release=0.001, reached=_panda_reached,
    open_joint=panda_hand.FINGER_TRAVEL_M)

DRIVES = {"2f85": TWO_F85, "panda": PANDA}
