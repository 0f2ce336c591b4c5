"""ROS 2 node for a Robotiq 2F-85 on Modbus RTU.

    ros2 run robotiq_driver gripper --ros-args -p port:=/dev/ttyUSB0

Publishes ``gripper/status`` (gravgrasp_msgs/GripperStatus) at ``status_rate_hz`` and
``/diagnostics`` at 1 Hz; serves ``gripper/move`` (gravgrasp_msgs/MoveGripper),
``gripper/activate``, ``gripper/open``, ``gripper/close`` and ``gripper/stop``
(std_srvs/Trigger; open and close use ``default_speed_mps`` / ``default_force_n`` and
answer when the fingers stop). Names are relative, so a
namespace or remap places them. If the port cannot be opened or the gripper stops
answering, the node keeps running, publishes ``connected: false`` and reconnects every
``reconnect_period_s``.

The node leaves the gripper alone on shutdown: the 2F-85's drive is self-locking, so
a held object stays held.
"""

from __future__ import annotations

import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from gravgrasp_msgs.msg import GripperStatus
from gravgrasp_msgs.srv import MoveGripper
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from std_srvs.srv import Trigger

from .gripper_client import GripperError, GripperLinkError, Robotiq2F85, describe_motion_end
from .gripper_registers import MAJOR_FAULTS, GripperCommand, GripperScale, GripperState
from .node_process import run_node

COMM_ERRORS = GripperLinkError  # the link is gone: reconnect (the driver raises only GripperError)


def _float_param(description, low, high):
    return ParameterDescriptor(
        description=description,
        floating_point_range=[FloatingPointRange(from_value=low, to_value=high)],
        read_only=True,
    )


def _int_param(description, low, high):
    return ParameterDescriptor(
        description=description, integer_range=[IntegerRange(from_value=low, to_value=high, step=1)], read_only=True
    )


class GripperNode(Node):
    def __init__(self):
        super().__init__("robotiq_gripper")
        p = self.declare_parameter
        self.port = p("port", "/dev/ttyUSB0", ParameterDescriptor(
            description="Serial device of the gripper's RS-485 adapter (or the emulator's pty)", read_only=True)).value
        self.slave_id = p("slave_id", 9, _int_param("Modbus slave address (factory default 9)", 1, 247)).value
        self.baudrate = p("baudrate", 115200, _int_param("Serial baud rate (the 2F-85 uses 115200)", 1200, 1000000)).value
        self.timeout_s = p("timeout_s", 0.1, _float_param("Answer timeout per Modbus attempt, s", 0.005, 5.0)).value
        self.retries = p("retries", 2, _int_param("Retries after a timeout or CRC error", 0, 10)).value
        rate = p("status_rate_hz", 20.0, _float_param("Status poll and publish rate, Hz", 1.0, 100.0)).value
        self.reconnect_period_s = p("reconnect_period_s", 1.0, _float_param(
            "Wait between attempts to (re)open the port, s", 0.1, 60.0)).value
        self.auto_activate = p("auto_activate", True, ParameterDescriptor(
            description="Activate the gripper on connection if it is not (the fingers open fully)",
            read_only=True)).value
        self.activation_timeout_s = p("activation_timeout_s", 5.0, _float_param(
            "Longest wait for an activation, s", 0.5, 60.0)).value
        self.motion_timeout_s = p("motion_timeout_s", 6.0, _float_param(
            "Longest wait for a motion with wait=true, s (a full stroke at 20 mm/s takes 4.3 s)",
            0.1, 60.0)).value
        self.default_speed_mps = p("default_speed_mps", 0.1, _float_param(
            "Finger speed of gripper/open and gripper/close, m/s", 0.020, 0.150)).value
        self.default_force_n = p("default_force_n", 40.0, _float_param(
            "Grip force of gripper/open and gripper/close, N", 20.0, 235.0)).value
        self.frame_id = p("frame_id", "robotiq_2f85", ParameterDescriptor(
            description="frame_id of the status messages", read_only=True)).value
        self.scale = GripperScale(
            stroke_m=p("stroke_m", 0.085, _float_param("Finger opening at open_counts, m", 0.01, 0.2)).value,
            open_counts=p("open_counts", 0, _int_param("Position counts when fully open (calibration)", 0, 254)).value,
            closed_counts=p("closed_counts", 255, _int_param(
                "Position counts when fully closed (calibration)", 1, 255)).value,
        )

        self._gripper: Robotiq2F85 | None = None
        self._connection_lock = threading.Lock()
        self._last_attempt = -float("inf")
        self._last_error = ""
        self._last_state: GripperState | None = None

        poll_group = MutuallyExclusiveCallbackGroup()
        service_group = ReentrantCallbackGroup()  # a waiting move must not block status
        self.status_pub = self.create_publisher(GripperStatus, "gripper/status", 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0 / rate, self._poll, callback_group=poll_group)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=poll_group)
        self.create_service(MoveGripper, "gripper/move", self._move, callback_group=service_group)
        self.create_service(Trigger, "gripper/activate", self._activate, callback_group=service_group)
        self.create_service(Trigger, "gripper/stop", self._stop, callback_group=service_group)
        self.create_service(Trigger, "gripper/open", self._open, callback_group=service_group)
        self.create_service(Trigger, "gripper/close", self._close, callback_group=service_group)
        self.get_logger().info(f"Robotiq 2F-85 on {self.port}, slave {self.slave_id}, {rate:g} Hz status")

    # -- connection ----------------------------------------------------------------

    def _connected_gripper(self) -> Robotiq2F85 | None:
        with self._connection_lock:
            if self._gripper is not None:
                return self._gripper
            now = time.monotonic()
            if now - self._last_attempt < self.reconnect_period_s:
                return None
            self._last_attempt = now
            try:
                gripper = Robotiq2F85(self.port, self.slave_id, self.baudrate, self.timeout_s, self.retries, self.scale)
            except GripperError as error:
                self._note_error(str(error))
                return None
            try:
                state = gripper.read_state()
                if self.auto_activate and not state.ready and state.activation_status == 0:
                    # Start it without waiting; the status poll shows its progress.
                    gripper.reset()
                    gripper.write_command(GripperCommand(activate=True))
            except COMM_ERRORS as error:
                gripper.close()
                self._note_error(f"{self.port} opened but the gripper does not answer: {error}")
                return None
            self._gripper = gripper
            self._last_error = ""
            self.get_logger().info(f"connected to the gripper on {self.port}")
            return gripper

    def _disconnect(self, error: Exception) -> None:
        with self._connection_lock:
            if self._gripper is not None:
                self._gripper.close()
                self._gripper = None
                self._last_attempt = time.monotonic()
        self._note_error(f"lost the gripper on {self.port}: {error}")

    def _note_error(self, text: str) -> None:
        if text != self._last_error:
            self.get_logger().error(text)
        self._last_error = text
        self._last_state = None

    # -- status --------------------------------------------------------------------

    def _poll(self) -> None:
        gripper = self._connected_gripper()
        state = None
        if gripper is not None:
            try:
                state = gripper.read_state()
            except COMM_ERRORS as error:
                self._disconnect(error)
        self._last_state = state
        self.status_pub.publish(self._status_msg(state))

    def _status_msg(self, state: GripperState | None) -> GripperStatus:
        msg = GripperStatus()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.frame_id
        msg.connected = state is not None
        if state is None:
            return msg
        msg.activated = state.ready
        msg.moving = state.moving
        msg.object_status = int(state.object_status)
        msg.object_detected = state.object_detected
        msg.position_m = self.scale.counts_to_width(state.position)
        msg.position_counts = state.position
        msg.requested_counts = state.requested
        msg.current_a = state.current_a
        msg.fault_code = state.fault
        msg.fault_text = state.fault_text
        return msg

    def _publish_diagnostics(self) -> None:
        state = self._last_state
        status = DiagnosticStatus(name="robotiq_driver: 2F-85", hardware_id=f"{self.port} slave {self.slave_id}")
        if state is None:
            status.level, status.message = DiagnosticStatus.ERROR, self._last_error or "not connected"
        elif state.fault in MAJOR_FAULTS:
            status.level, status.message = DiagnosticStatus.ERROR, f"fault 0x{state.fault:02X}: {state.fault_text}"
        elif state.fault:
            status.level, status.message = DiagnosticStatus.WARN, f"fault 0x{state.fault:02X}: {state.fault_text}"
        elif not state.ready:
            status.level, status.message = DiagnosticStatus.WARN, "not activated"
        else:
            status.level, status.message = DiagnosticStatus.OK, "ready"
        gripper = self._gripper
        values = {"port": self.port, "slave_id": self.slave_id}
        if gripper is not None:
            values.update(transactions=gripper.modbus.transactions, failed_attempts=gripper.modbus.failed_attempts)
        if state is not None:
            values.update(
                gSTA=int(state.activation_status), gOBJ=int(state.object_status), gFLT=state.fault,
                position_m=f"{self.scale.counts_to_width(state.position):.4f}",
            )
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(msg)

    # -- services ------------------------------------------------------------------

    def _move(self, request: MoveGripper.Request, response: MoveGripper.Response) -> MoveGripper.Response:
        response.success, response.message, state = self._do_move(
            request.position_m, request.speed_mps, request.force_n, request.wait
        )
        response.status = self._status_msg(state)
        return response

    def _open(self, request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message, _ = self._do_move(
            self.scale.stroke_m, self.default_speed_mps, self.default_force_n, wait=True
        )
        return response

    def _close(self, request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message, _ = self._do_move(
            0.0, self.default_speed_mps, self.default_force_n, wait=True
        )
        return response

    def _do_move(self, position_m, speed_mps, force_n, wait) -> tuple[bool, str, GripperState | None]:
        """Move (and with ``wait`` wait for the fingers to stop): (success, message, state)."""
        gripper = self._gripper
        if gripper is None:
            return False, f"gripper not connected on {self.port}: {self._last_error or 'connecting'}", None
        try:
            requested = gripper.move(position_m, speed_mps, force_n)
            state = gripper.wait(self.motion_timeout_s, requested) if wait else gripper.read_state()
        except ValueError as error:
            return False, f"rejected: {error}", self._last_state
        except COMM_ERRORS as error:
            self._disconnect(error)
            return False, f"communication with the gripper failed: {error}", None
        except GripperError as error:
            return False, str(error), self._last_state
        if not wait:
            return True, f"moving to {position_m * 1e3:.1f} mm", state
        return True, describe_motion_end(state, self.scale.counts_to_width(state.position)), state

    def _activate(self, request, response: Trigger.Response) -> Trigger.Response:
        gripper = self._gripper
        if gripper is None:
            response.message = f"gripper not connected on {self.port}: {self._last_error or 'connecting'}"
            return response
        try:
            faulted = gripper.read_state().fault != 0
            gripper.activate(self.activation_timeout_s, force=faulted)
            response.success, response.message = True, "activated"
        except COMM_ERRORS as error:
            self._disconnect(error)
            response.message = f"communication with the gripper failed: {error}"
        except GripperError as error:
            response.message = str(error)
        return response

    def _stop(self, request, response: Trigger.Response) -> Trigger.Response:
        gripper = self._gripper
        if gripper is None:
            response.message = f"gripper not connected on {self.port}"
            return response
        try:
            gripper.stop()
            response.success, response.message = True, "stopped"
        except COMM_ERRORS as error:
            self._disconnect(error)
            response.message = f"communication with the gripper failed: {error}"
        return response

    def destroy_node(self):
        with self._connection_lock:
            if self._gripper is not None:
                self._gripper.close()
                self._gripper = None
        return super().destroy_node()


def main(args=None):
    return run_node("gripper", GripperNode, (ValueError, InvalidParameterValueException), threads=3, args=args)


if __name__ == "__main__":
    sys.exit(main())
