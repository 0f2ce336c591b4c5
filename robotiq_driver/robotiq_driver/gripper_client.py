"""Driver for a Robotiq 2F-85 on a serial port (RS-485 adapter, or the emulator's pty).

Blocking and thread-safe: each Modbus transaction holds a lock, so a status poller and
a motion request can share one instance. Units at this interface are SI (m, m/s, N);
counts stay inside. The line is pymodbus's RTU serial client (``modbus_client``): every
call has a timeout and bounded retries, and a port that fails (adapter unplugged) is
reopened by path on the next attempt.
"""

from __future__ import annotations

import contextlib
import threading
import time

from .gripper_registers import (
    BAUDRATE,
    COMMAND_ADDRESS,
    MAJOR_FAULTS,
    REGISTER_COUNT,
    SLAVE_ID,
    STATUS_ADDRESS,
    GripperCommand,
    GripperScale,
    GripperState,
    ObjectStatus,
    fault_text,
)
from .modbus_client import ModbusConnectionError, ModbusError, ModbusRtuClient

FAULT_ACTION_DELAYED = 0x05


class GripperError(Exception):
    """Base class of every error `Robotiq2F85` raises (besides ValueError for bad arguments)."""


class GripperConnectionError(GripperError):
    """The serial port could not be opened."""


class GripperLinkError(GripperError):
    """The Modbus RTU line failed: no valid answer after the retries, an exception
    response, answers that do not fit the request, or a port that could not be
    reopened. The `modbus_client.ModbusError` (ModbusTimeout, ModbusExceptionResponse,
    ModbusFrameError, ModbusConnectionError) is its __cause__."""


class GripperNotReady(GripperError):
    """A motion was requested before the activation completed."""


class GripperFault(GripperError):
    def __init__(self, code: int, during: str):
        self.code = code
        super().__init__(f"gripper fault 0x{code:02X} during {during}: {fault_text(code)}")


class GripperTimeout(GripperError):
    """The gripper answered, but did not reach the expected state in time."""


def describe_motion_end(state: GripperState, width_m: float) -> str:
    """How a finished motion ended, in one phrase (gOBJ and the final opening)."""
    width_mm = width_m * 1e3
    if state.object_status == ObjectStatus.CONTACT_CLOSING:
        return f"stopped on an object while closing, at {width_mm:.1f} mm"
    if state.object_status == ObjectStatus.CONTACT_OPENING:
        return f"stopped on an object while opening, at {width_mm:.1f} mm"
    return f"reached {width_mm:.1f} mm, no object"


@contextlib.contextmanager
def _link_errors():
    """The line's ModbusError as the driver's own GripperLinkError (same message)."""
    try:
        yield
    except ModbusError as error:
        raise GripperLinkError(str(error)) from error


class Robotiq2F85:
    def __init__(
        self,
        port: str,
        slave_id: int = SLAVE_ID,
        baudrate: int = BAUDRATE,
        timeout_s: float = 0.1,
        retries: int = 2,
        scale: GripperScale = GripperScale(),
        status_function: int = 0x03,
    ):
        """``status_function``: 0x03 (read holding registers, as the manual's examples)
        or 0x04 (read input registers); the 2F-85 answers both at 0x07D0."""
        if not 1 <= slave_id <= 247:
            raise ValueError(f"slave_id {slave_id} out of range 1..247 (the 2F-85 ships as 9)")
        if status_function not in (0x03, 0x04):
            raise ValueError(f"status_function 0x{status_function:02X}: use 0x03 or 0x04")
        self.port = port
        self.slave_id = slave_id
        self.scale = scale
        self.status_function = status_function
        # 8N1 as the 2F-85 ships; the port is opened exclusively (a second driver on the
        # same port would interleave frames).
        self.modbus = ModbusRtuClient(port, baudrate=baudrate, timeout_s=timeout_s, retries=retries)
        try:
            self.modbus.connect()
        except ModbusConnectionError as error:
            raise GripperConnectionError(
                f"{error}. Check the path (e.g. ls -l /dev/serial/by-id/), "
                "that your user may open it (dialout group) and that no other program holds it."
            ) from error
        self._lock = threading.Lock()
        self._last_command = GripperCommand()

    def close(self) -> None:
        with self._lock:
            self.modbus.close()

    def __enter__(self) -> "Robotiq2F85":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- registers ---------------------------------------------------------------

    def read_state(self) -> GripperState:
        with self._lock, _link_errors():
            if self.status_function == 0x04:
                registers = self.modbus.read_input_registers(self.slave_id, STATUS_ADDRESS, REGISTER_COUNT)
            else:
                registers = self.modbus.read_holding_registers(self.slave_id, STATUS_ADDRESS, REGISTER_COUNT)
        return GripperState.from_registers(registers)

    def write_command(self, command: GripperCommand) -> None:
        with self._lock, _link_errors():
            self.modbus.write_registers(self.slave_id, COMMAND_ADDRESS, command.to_registers())
            self._last_command = command

    def width_m(self, state: GripperState) -> float:
        return self.scale.counts_to_width(state.position)

    # -- actions -----------------------------------------------------------------

    def reset(self) -> None:
        """rACT = 0: stops the fingers, clears faults; an activation must follow."""
        self.write_command(GripperCommand())

    def activate(self, timeout_s: float = 5.0, force: bool = False) -> GripperState:
        """Activate (reset first) and wait for gSTA = 3. A no-op if already active with
        no major fault latched (one only clears with rACT 0 -> 1), unless ``force``. The
        fingers open fully during activation."""
        state = self.read_state()
        if state.ready and state.fault not in MAJOR_FAULTS and not force:
            return state
        self.reset()
        self.write_command(GripperCommand(activate=True))
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.read_state()
            if state.ready:
                return state
            if state.fault in MAJOR_FAULTS:
                raise GripperFault(state.fault, "activation")
            if time.monotonic() > deadline:
                raise GripperTimeout(
                    f"activation not complete after {timeout_s} s (gSTA = {state.activation_status}): "
                    "check that nothing blocks the fingers, then retry"
                )
            time.sleep(0.02)

    def move(self, width_m: float, speed_mps: float, force_n: float) -> int:
        """Start a motion to an opening of ``width_m``; return the requested counts.

        Values outside the gripper's range raise ValueError (they are not clamped).
        """
        command = GripperCommand(
            activate=True,
            go=True,
            position=self.scale.width_to_counts(width_m),
            speed=self.scale.speed_to_counts(speed_mps),
            force=self.scale.force_to_counts(force_n),
        )
        state = self.read_state()
        if not state.ready:
            raise GripperNotReady(
                f"gripper not activated (gACT = {int(state.activated)}, gSTA = {int(state.activation_status)}): "
                "activate it first"
            )
        if state.fault in MAJOR_FAULTS:
            raise GripperFault(state.fault, "motion request")
        self.write_command(command)
        return command.position

    def wait(self, timeout_s: float, requested: int | None = None, poll_s: float = 0.01,
             echo_timeout_s: float = 0.5) -> GripperState:
        """Poll until the current motion ends (gOBJ != 0) and return the final state.

        ``requested``: counts returned by ``move``; until gPR echoes them the gripper
        has not taken the command yet, and an old gOBJ must not end the wait. The
        gripper echoes a command at once; one not echoed within ``echo_timeout_s`` was
        lost on the line (its acknowledgement was another request's late answer), so
        it is written again: a command is a register state, repeating it is harmless.
        """
        start = resent = time.monotonic()
        deadline = start + timeout_s
        resends = 0
        while True:
            state = self.read_state()
            if state.fault and state.fault != FAULT_ACTION_DELAYED:
                raise GripperFault(state.fault, "motion")
            taken = requested is None or state.requested == requested
            if state.go and taken and state.object_status != ObjectStatus.MOVING:
                return state
            now = time.monotonic()
            if now > deadline:
                lost = "" if taken else f"; the command was sent {resends + 1} times and never taken"
                raise GripperTimeout(
                    f"motion not finished after {timeout_s} s (position {state.position} counts, "
                    f"requested {state.requested}, gOBJ = {int(state.object_status)}{lost})"
                )
            if not taken and state.ready and now - resent > echo_timeout_s \
                    and self._last_command.position == requested:
                self.write_command(self._last_command)
                resent, resends = time.monotonic(), resends + 1
            time.sleep(poll_s)

    def move_and_wait(self, width_m: float, speed_mps: float, force_n: float, timeout_s: float) -> GripperState:
        return self.wait(timeout_s, requested=self.move(width_m, speed_mps, force_n))

    def stop(self) -> None:
        """rGTO = 0: the fingers stop where they are."""
        last = self._last_command
        self.write_command(
            GripperCommand(activate=True, go=False, position=last.position, speed=last.speed, force=last.force)
        )

    def auto_release(self, open_fingers: bool = True) -> None:
        """Emergency release at minimum speed; a reset and activation are needed after."""
        self.write_command(GripperCommand(activate=True, auto_release=True, auto_release_open=open_fingers))
