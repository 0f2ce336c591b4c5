"""Register-level emulator of a Robotiq 2F-85: the gripper's state machine behind its
Modbus registers, with the fingers' motion delegated to a ``FingerPlant``.

What it reproduces (2F-85 manual, Modbus RTU section):
- rACT = 0 resets (gSTA 0, faults cleared); a rising edge of rACT starts an activation
  that takes ``activation_time_s`` and leaves the fingers open (gSTA 1, then 3).
- rGTO = 1 once activated starts a motion to rPR at rSP/rFR. gOBJ is 0 while the
  fingers move, 2 (1) when they stop on an object while closing (opening), 3 at rPR.
  If a held object goes away the fingers move on, and gOBJ ends at 3: how the real
  gripper reports a dropped object.
- rGTO = 0 stops the fingers where they are.
- rGTO without rACT gives fault 0x07; rGTO during activation gives 0x05 and the motion
  starts when the activation completes.
- rATR = 1 releases towards open (rARD = 1) or closed at minimum speed, with fault 0x0B
  during and 0x0F after, until a reset.
- Major faults (``inject_fault``, e.g. 0x0E overcurrent) stop the fingers and hold
  until a reset.
- gCU: 0.10 A while the fingers move, 0 once they stop: the 2F-85's drive is
  self-locking, so a grip holds unpowered (the manual's example frames show gCU 0 after
  contact). A plant can report its own current.

Time comes from ``clock`` (monotonic seconds), so tests can drive it by hand.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable, Protocol

from ..gripper_registers import (
    COMMAND_ADDRESS,
    CURRENT_A_PER_COUNT,
    MAJOR_FAULTS,
    REGISTER_COUNT,
    STATUS_ADDRESS,
    ActivationStatus,
    GripperCommand,
    GripperScale,
    GripperState,
    ObjectStatus,
)

ILLEGAL_DATA_ADDRESS = 0x02  # Modbus exception code
FAULT_ACTION_DELAYED = 0x05
FAULT_ACTIVATION_BIT = 0x07
FAULT_RELEASE_IN_PROGRESS = 0x0B
FAULT_RELEASE_COMPLETED = 0x0F


class DeviceException(Exception):
    """Raised by the register interface to make the Modbus server answer with the
    exception ``code`` (e.g. 0x02, illegal data address)."""

    def __init__(self, code: int, reason: str = ""):
        self.code = code
        super().__init__(reason or f"Modbus exception 0x{code:02X}")


@dataclass(frozen=True)
class FingerReading:
    width_m: float  # finger opening after the step
    blocked: bool  # the fingers are stopped by contact short of the target
    current_a: float  # motor current


class FingerPlant(Protocol):
    """What moves the fingers. A physics simulation implements this to drive the
    emulator's registers from simulated contact."""

    def advance(
        self, dt_s: float, width_m: float, target_width_m: float, speed_mps: float, force_n: float
    ) -> FingerReading: ...


@dataclass
class KinematicFingers:
    """Fingers that move at the commanded speed and stop on a rigid object.

    ``object_width_m``: width of an object between the fingers (stops a closing
    motion). ``inner_width_m``: width of an object the fingers are inside of, e.g. a
    ring (stops an opening motion). None means no object. Both may be changed at any
    time, e.g. set ``object_width_m = None`` to emulate a dropped object.

    ``fingers_meet_m``: the opening at which the fingertips touch each other. A real
    2F-85 asked to close fully on nothing can stop there and report an object (gOBJ 2),
    at an opening that differs from unit to unit; 0 (the default) closes to 0 and
    reports "at position" (gOBJ 3).
    """

    object_width_m: float | None = None
    inner_width_m: float | None = None
    moving_current_a: float = 0.10
    fingers_meet_m: float = 0.0

    def advance(self, dt_s, width_m, target_width_m, speed_mps, force_n) -> FingerReading:
        step = speed_mps * dt_s
        delta = min(max(target_width_m - width_m, -step), step)
        new = width_m + delta
        blocked = False
        if target_width_m < width_m:
            obj = self.object_width_m
            if self.fingers_meet_m > 0 and (obj is None or obj < self.fingers_meet_m):
                obj = self.fingers_meet_m  # nothing thinner fits between touching fingertips
            if obj is not None and width_m >= obj - 1e-9 and target_width_m < obj and new <= obj:
                new, blocked = obj, True
        if target_width_m > width_m:
            inner = self.inner_width_m
            if inner is not None and width_m <= inner + 1e-9 and target_width_m > inner and new >= inner:
                new, blocked = inner, True
        at_target = abs(new - target_width_m) < 1e-9
        current = 0.0 if blocked or at_target else self.moving_current_a
        return FingerReading(new, blocked, current)


class GripperEmulator:
    """The 2F-85's registers and state machine; thread-safe.

    ``read_registers``/``write_registers`` are what a Modbus server calls (they raise
    ``DeviceException`` for unmapped addresses); ``state``, ``command`` and
    ``inject_fault`` are for simulations and tests.
    """

    def __init__(
        self,
        plant: FingerPlant | None = None,
        scale: GripperScale = GripperScale(),
        activation_time_s: float = 1.0,
        initial_width_m: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        if activation_time_s < 0:
            raise ValueError(f"activation_time_s must be >= 0, got {activation_time_s}")
        self.plant = plant if plant is not None else KinematicFingers()
        self.scale = scale
        self.activation_time_s = activation_time_s
        self.clock = clock
        self._lock = threading.RLock()
        self._command = GripperCommand()
        self._width_m = scale.stroke_m / 2 if initial_width_m is None else initial_width_m
        self._activated = False
        self._go = False
        self._status = ActivationStatus.RESET
        self._object = ObjectStatus.MOVING
        self._fault = 0
        self._requested = 0
        self._current_a = 0.0
        self._activation_end: float | None = None
        self._moving = False
        self._releasing = False
        self._target_m = self._width_m
        self._speed_mps = scale.min_speed_mps
        self._force_n = scale.min_force_n
        self._last_time = clock()

    # -- Modbus side --------------------------------------------------------------

    def read_registers(self, address: int, count: int) -> list[int]:
        with self._lock:
            self.advance()
            blocks = {
                STATUS_ADDRESS: self.state.to_registers(),
                COMMAND_ADDRESS: self._command.to_registers(),
            }
            for start, values in blocks.items():
                if start <= address and address + count <= start + REGISTER_COUNT:
                    return list(values[address - start : address - start + count])
        raise DeviceException(
            ILLEGAL_DATA_ADDRESS,
            f"registers {address}..{address + count - 1} are not mapped "
            f"(status 0x{STATUS_ADDRESS:04X}..+2, command 0x{COMMAND_ADDRESS:04X}..+2)",
        )

    def write_registers(self, address: int, values) -> None:
        values = list(values)
        if not (COMMAND_ADDRESS <= address and address + len(values) <= COMMAND_ADDRESS + REGISTER_COUNT):
            raise DeviceException(
                ILLEGAL_DATA_ADDRESS,
                f"registers {address}..{address + len(values) - 1} are not writable "
                f"(command registers are 0x{COMMAND_ADDRESS:04X}..+2)",
            )
        with self._lock:
            self.advance()
            registers = list(self._command.to_registers())
            registers[address - COMMAND_ADDRESS : address - COMMAND_ADDRESS + len(values)] = values
            previous, self._command = self._command, GripperCommand.from_registers(registers)
            self._apply(previous, self._command)

    # -- simulation side ----------------------------------------------------------

    @property
    def state(self) -> GripperState:
        with self._lock:
            return GripperState(
                activated=self._activated,
                go=self._go,
                activation_status=self._status,
                object_status=self._object,
                fault=self._fault,
                requested=self._requested,
                position=self._position_counts(),
                current=min(255, round(self._current_a / CURRENT_A_PER_COUNT)),
            )

    @property
    def command(self) -> GripperCommand:
        return self._command

    @property
    def width_m(self) -> float:
        return self._width_m

    def inject_fault(self, code: int) -> None:
        """Raise gFLT = ``code``; a major fault stops the fingers until a reset."""
        with self._lock:
            self.advance()
            self._fault = code
            if code in MAJOR_FAULTS:
                self._moving = self._releasing = False
                self._current_a = 0.0

    def advance(self, now: float | None = None) -> None:
        """Move the emulated gripper on to ``now`` (default: the clock)."""
        with self._lock:
            now = self.clock() if now is None else now
            dt = max(0.0, now - self._last_time)
            self._last_time = now
            if self._status == ActivationStatus.ACTIVATING:
                self._advance_activation(now, dt)
            if self._moving:
                self._advance_motion(dt)

    # -- state machine -------------------------------------------------------------

    def _position_counts(self) -> int:
        s = self.scale
        counts = s.closed_counts - self._width_m / s.stroke_m * (s.closed_counts - s.open_counts)
        return min(255, max(0, round(counts)))

    def _apply(self, previous: GripperCommand, cmd: GripperCommand) -> None:
        if cmd.auto_release and self._fault != FAULT_RELEASE_COMPLETED:
            if not self._releasing:
                self._releasing = self._moving = True
                self._go = False
                self._fault = FAULT_RELEASE_IN_PROGRESS
                self._target_m = self.scale.stroke_m if cmd.auto_release_open else 0.0
                self._speed_mps = self.scale.min_speed_mps
                self._force_n = self.scale.min_force_n
            return
        if self._releasing or self._fault == FAULT_RELEASE_COMPLETED:
            if not cmd.activate:
                self._reset()
            return
        if not cmd.activate:
            self._reset()
            if cmd.go:
                self._fault = FAULT_ACTIVATION_BIT
            return
        if not previous.activate and self._status == ActivationStatus.RESET:
            self._activated = True
            self._status = ActivationStatus.ACTIVATING
            self._activation_end = self._last_time + self.activation_time_s
            self._fault = 0
        if self._fault in MAJOR_FAULTS:
            return  # only a reset clears a major fault
        if not cmd.go:
            self._stop()
        elif self._status == ActivationStatus.ACTIVATING:
            self._fault = FAULT_ACTION_DELAYED
        elif self._status == ActivationStatus.ACTIVATED:
            self._start_motion(cmd)

    def _reset(self) -> None:
        self._activated = self._go = self._moving = self._releasing = False
        self._status = ActivationStatus.RESET
        self._object = ObjectStatus.MOVING
        self._fault = 0
        self._current_a = 0.0
        self._activation_end = None

    def _stop(self) -> None:
        self._go = self._moving = False
        self._current_a = 0.0

    def _start_motion(self, cmd: GripperCommand) -> None:
        self._fault = 0
        self._go = self._moving = True
        self._object = ObjectStatus.MOVING
        self._requested = cmd.position
        self._target_m = self.scale.counts_to_width(cmd.position)
        self._speed_mps = self.scale.counts_to_speed(cmd.speed)
        self._force_n = self.scale.counts_to_force(cmd.force)

    def _advance_activation(self, now: float, dt: float) -> None:
        # The real activation opens and closes the fingers to find the stroke; the
        # emulator only opens them, at full speed, and ends open.
        step = self.scale.max_speed_mps * dt
        self._width_m = min(self.scale.stroke_m, self._width_m + step)
        self._current_a = 0.10
        if now >= self._activation_end:
            self._status = ActivationStatus.ACTIVATED
            self._width_m = self.scale.stroke_m
            self._current_a = 0.0
            self._activation_end = None
            if self._fault == FAULT_ACTION_DELAYED:
                self._fault = 0
                if self._command.go:
                    self._start_motion(self._command)

    def _advance_motion(self, dt: float) -> None:
        reading = self.plant.advance(dt, self._width_m, self._target_m, self._speed_mps, self._force_n)
        self._width_m = min(max(reading.width_m, 0.0), self.scale.stroke_m)
        self._current_a = reading.current_a
        at_target = abs(self._width_m - self._target_m) < 1e-6
        if self._releasing:
            if reading.blocked or at_target:
                self._releasing = self._moving = False
                self._fault = FAULT_RELEASE_COMPLETED
                self._status = ActivationStatus.RESET
            return
        if reading.blocked:
            closing = self._target_m < self._width_m
            self._object = ObjectStatus.CONTACT_CLOSING if closing else ObjectStatus.CONTACT_OPENING
        elif at_target:
            self._object = ObjectStatus.AT_POSITION
        else:
            self._object = ObjectStatus.MOVING
