"""Register map of the Robotiq 2F-85 and the conversions between counts and SI units.

From the 2F-85/2F-140 instruction manual (Modbus RTU section). The robot writes three
*output* registers at 0x03E8 and reads three *input* registers at 0x07D0; each
register holds two of the six bytes below, first byte in the high half.

    output (robot -> gripper)               input (gripper -> robot)
    byte 0  action request                  byte 0  gripper status
            bit 0 rACT  activate                    bit 0    gACT  activation echo
            bit 3 rGTO  go to rPR                   bit 3    gGTO  go-to echo
            bit 4 rATR  automatic release           bits 4-5 gSTA  0 reset, 1 activating, 3 ready
            bit 5 rARD  release direction (1 open)  bits 6-7 gOBJ  object detection, below
    byte 1  reserved                        byte 1  reserved
    byte 2  reserved                        byte 2  fault: low nibble gFLT, high nibble kFLT
    byte 3  rPR position request            byte 3  gPR position request echo
    byte 4  rSP speed                       byte 4  gPO position
    byte 5  rFR force                       byte 5  gCU motor current, 10 mA per count

Position counts run from 0 (open) to 255 (closed), speed and force from 0 (minimum)
to 255 (maximum). ``GripperScale`` maps them to metres, metres per second and newtons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

SLAVE_ID = 9  # factory default
BAUDRATE = 115200  # 8 data bits, no parity, 1 stop bit
COMMAND_ADDRESS = 0x03E8
STATUS_ADDRESS = 0x07D0
REGISTER_COUNT = 3
CURRENT_A_PER_COUNT = 0.01


class ActivationStatus(IntEnum):
    """gSTA."""

    RESET = 0  # in reset (or automatic release) state
    ACTIVATING = 1
    UNUSED = 2
    ACTIVATED = 3


class ObjectStatus(IntEnum):
    """gOBJ; same numbering as gravgrasp_msgs/GripperStatus.object_status."""

    MOVING = 0  # fingers moving towards rPR, no object detected
    CONTACT_OPENING = 1  # fingers stopped on contact while opening
    CONTACT_CLOSING = 2  # fingers stopped on contact while closing
    AT_POSITION = 3  # fingers at rPR, no object detected (or object lost/dropped)


# gFLT. Minor faults (0x05-0x08) clear once the cause is gone, major ones (0x0A-0x0F)
# need a reset (rACT = 0) and a new activation.
FAULT_TEXT = {
    0x00: "",
    0x05: "action delayed: the activation (re-activation) must complete before the action",
    0x07: "the activation bit (rACT) must be set before an action is requested",
    0x08: "maximum operating temperature exceeded (>= 85 C): let the gripper cool down",
    0x09: "no communication for at least 1 second",
    0x0A: "under minimum operating voltage: check the 24 V supply",
    0x0B: "automatic release in progress",
    0x0C: "internal fault: contact Robotiq support",
    0x0D: "activation fault: check that nothing obstructs the fingers, then reset and activate",
    0x0E: "overcurrent triggered: reset and activate again",
    0x0F: "automatic release completed: reset and activate again",
}
MAJOR_FAULTS = frozenset({0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F})


def fault_text(code: int) -> str:
    """Sentence for a gFLT code; empty for 0."""
    return FAULT_TEXT.get(code, f"unknown fault code 0x{code:02X}")


def _byte(name: str, value: int) -> int:
    if not 0 <= int(value) <= 255:
        raise ValueError(f"{name} = {value} does not fit a byte (0..255)")
    return int(value)


@dataclass(frozen=True)
class GripperCommand:
    """The output registers (robot -> gripper), in counts."""

    activate: bool = False  # rACT
    go: bool = False  # rGTO
    auto_release: bool = False  # rATR
    auto_release_open: bool = False  # rARD: True releases by opening
    position: int = 0  # rPR, 0 open .. 255 closed
    speed: int = 0  # rSP
    force: int = 0  # rFR

    def to_registers(self) -> tuple[int, int, int]:
        action = (
            int(self.activate)
            | int(self.go) << 3
            | int(self.auto_release) << 4
            | int(self.auto_release_open) << 5
        )
        return (
            action << 8,
            _byte("rPR", self.position),
            _byte("rSP", self.speed) << 8 | _byte("rFR", self.force),
        )

    @classmethod
    def from_registers(cls, registers) -> "GripperCommand":
        r0, r1, r2 = registers
        action = r0 >> 8
        return cls(
            activate=bool(action & 0x01),
            go=bool(action & 0x08),
            auto_release=bool(action & 0x10),
            auto_release_open=bool(action & 0x20),
            position=r1 & 0xFF,
            speed=r2 >> 8,
            force=r2 & 0xFF,
        )


@dataclass(frozen=True)
class GripperState:
    """The input registers (gripper -> robot), in counts."""

    activated: bool = False  # gACT
    go: bool = False  # gGTO
    activation_status: int = ActivationStatus.RESET  # gSTA
    object_status: int = ObjectStatus.MOVING  # gOBJ
    fault: int = 0  # gFLT
    controller_fault: int = 0  # kFLT
    requested: int = 0  # gPR
    position: int = 0  # gPO
    current: int = 0  # gCU, 10 mA per count

    def to_registers(self) -> tuple[int, int, int]:
        status = (
            int(self.activated)
            | int(self.go) << 3
            | (int(self.activation_status) & 0x3) << 4
            | (int(self.object_status) & 0x3) << 6
        )
        faults = (int(self.controller_fault) & 0xF) << 4 | (int(self.fault) & 0xF)
        return (
            status << 8,
            faults << 8 | _byte("gPR", self.requested),
            _byte("gPO", self.position) << 8 | _byte("gCU", self.current),
        )

    @classmethod
    def from_registers(cls, registers) -> "GripperState":
        r0, r1, r2 = registers
        status, faults = r0 >> 8, r1 >> 8
        return cls(
            activated=bool(status & 0x01),
            go=bool(status & 0x08),
            activation_status=ActivationStatus((status >> 4) & 0x3),
            object_status=ObjectStatus((status >> 6) & 0x3),
            fault=faults & 0xF,
            controller_fault=faults >> 4,
            requested=r1 & 0xFF,
            position=r2 >> 8,
            current=r2 & 0xFF,
        )

    @property
    def ready(self) -> bool:
        """Activation complete, so motion requests are obeyed."""
        return self.activated and self.activation_status == ActivationStatus.ACTIVATED

    @property
    def moving(self) -> bool:
        return self.go and self.object_status == ObjectStatus.MOVING

    @property
    def object_detected(self) -> bool:
        return self.object_status in (ObjectStatus.CONTACT_OPENING, ObjectStatus.CONTACT_CLOSING)

    @property
    def current_a(self) -> float:
        return self.current * CURRENT_A_PER_COUNT

    @property
    def fault_text(self) -> str:
        return fault_text(self.fault)


@dataclass(frozen=True)
class GripperScale:
    """Linear maps between counts and SI units, with the 2F-85's nominal ranges.

    ``open_counts``/``closed_counts`` are the position counts at ``stroke_m`` and at
    zero opening; the nominal 0/255 can be replaced by a unit's calibration.
    """

    stroke_m: float = 0.085
    open_counts: int = 0
    closed_counts: int = 255
    min_speed_mps: float = 0.020
    max_speed_mps: float = 0.150
    min_force_n: float = 20.0
    max_force_n: float = 235.0

    def __post_init__(self):
        if not self.stroke_m > 0:
            raise ValueError(f"stroke_m must be > 0, got {self.stroke_m}")
        if not 0 <= self.open_counts < self.closed_counts <= 255:
            raise ValueError(
                f"need 0 <= open_counts < closed_counts <= 255, got {self.open_counts}, {self.closed_counts}"
            )

    @staticmethod
    def _check(name: str, value: float, low: float, high: float, unit: str) -> float:
        value = float(value)
        # Slack of 1e-6 of the range, so that limits sent as float32 (0.15 arrives as
        # 0.15000000596) are accepted; they are then clamped onto the range.
        slack = 1e-6 * (high - low)
        if not math.isfinite(value) or not low - slack <= value <= high + slack:
            raise ValueError(f"{name} = {value:.6g} {unit} is outside the gripper's range {low}..{high} {unit}")
        return min(max(value, low), high)

    def width_to_counts(self, width_m: float) -> int:
        width_m = self._check("position", width_m, 0.0, self.stroke_m, "m")
        span = self.closed_counts - self.open_counts
        return round(self.closed_counts - width_m / self.stroke_m * span)

    def counts_to_width(self, counts: float) -> float:
        span = self.closed_counts - self.open_counts
        width = (self.closed_counts - counts) / span * self.stroke_m
        return min(max(width, 0.0), self.stroke_m)

    def speed_to_counts(self, speed_mps: float) -> int:
        speed_mps = self._check("speed", speed_mps, self.min_speed_mps, self.max_speed_mps, "m/s")
        return round((speed_mps - self.min_speed_mps) / (self.max_speed_mps - self.min_speed_mps) * 255)

    def counts_to_speed(self, counts: int) -> float:
        return self.min_speed_mps + counts / 255 * (self.max_speed_mps - self.min_speed_mps)

    def force_to_counts(self, force_n: float) -> int:
        force_n = self._check("force", force_n, self.min_force_n, self.max_force_n, "N")
        return round((force_n - self.min_force_n) / (self.max_force_n - self.min_force_n) * 255)

    def counts_to_force(self, counts: int) -> float:
        return self.min_force_n + counts / 255 * (self.max_force_n - self.min_force_n)
