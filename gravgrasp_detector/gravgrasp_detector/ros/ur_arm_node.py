"""`ros2 run gravgrasp_detector ur_arm`: a Universal Robots arm as the executor's arm.

    ros2 run gravgrasp_detector ur_arm --ros-args -p robot_ip:=192.168.1.102

Serves the same interface as the Drake sim bridge, so the executor cannot tell them apart:

| name | type | |
| --- | --- | --- |
| `move_to_pose` | gravgrasp_msgs/MoveToPose | straight-line TCP motion (moveL) to a pose in `frame_id`; `check_only` asks the controller (safety limits, IK) without moving; past its `deadline` a request is refused, a motion stopped |
| `stop_motion` | std_srvs/Trigger | halts the running motion at once (stopL; its `move_to_pose` answers `success: false`) |
| `~/reconnect` | std_srvs/Trigger | drop the RTDE connection and build it again (never needed after a cleared stop: ur_arm restarts its control script itself) |
| `emergency_stop` (sub) | std_msgs/Bool | `true` halts the running motion (stopL) and latches: every motion is refused until `~/arm` |
| `~/arm` | std_srvs/SetBool | `true` clears the latch (motion allowed again), `false` latches it |
| `flange_pose` | geometry_msgs/PoseStamped | the tool flange in `frame_id`, at `state_rate_hz` |
| `flange_pose_base` | geometry_msgs/PoseStamped | the same in the robot base frame `base_frame_id` (calibrate_camera's robot poses: the result does not depend on the workspace origin) |
| `camera_pose` | geometry_msgs/PoseStamped | only with `camera_in_flange` set (a camera on the wrist): its optical frame in `frame_id`, for the tsdf node; sensor-data QoS |

A thin adapter around `ur_arm.URArm` (frames, limits, stop, timeouts; see there) over
ur_rtde's RTDEControlInterface/RTDEReceiveInterface. The node keeps serving while the
robot is unreachable: requests are answered with why, and it reconnects (or restarts the
control script after a cleared protective or emergency stop) every `reconnect_period_s`.
Between requests, at `state_rate_hz`, it watches the arm stand still (URArm.watch): a
motion nobody asked for is stopped and latched until `~/arm`.
Once serving it logs ``ur_arm ready``.

Monitoring only (pendant in Local mode), a flange pose is published only while the
controller's TCP, judged from the joint angles, is `tcp_in_flange` (execution/ur_arm.py); otherwise
one error line says what to set. `camera_in_base` and the `calibration_*` values are
calibrate_camera's record of an eye-to-hand camera; the stack composes the tsdf node's
`camera_pose` from them and `stack.workspace_origin_in_base` (cell_config.py). The failure paths, each with its test:
gravgrasp_detector/doc/arm-adapter.md.
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np
from gravgrasp_msgs.srv import MoveToPose
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from ..execution.ur_arm import ConnectionLost, TCPMismatch, URArm
from ..execution.ur_arm_settings import FLANGE_TO_TCP_2F85_M, URArmSettings, xyz_yaw_to_matrix
from ..poses import PoseError, matrix_from_pose
from .interface import (described, float_range, matrix_from_pose_msg, monotonic_deadline, pose_stamped_from_matrix,
                        run_node)

UNREACHABLE_HINT = ("check the Ethernet cable and robot_ip (pendant: Settings > System > Network), that the robot "
                    "is in Remote Control (e-Series), and that no other program holds its RTDE interface")


def rtde_connect(robot_ip: str, frequency_hz: float):
    """connect(receive) for URArm over the real ur_rtde; a live receive interface passed in
    (while only watching) is kept, so flange_pose has no gap."""
    def connect(receive=None):
        try:  # lazy: ur_rtde is optional (only a real arm needs it; the core and tests never do)
            import rtde_control
            import rtde_receive
        except ImportError as e:
            raise RuntimeError(f"ur_rtde is not installed ({e}): pip install ur-rtde==1.6.5") from None
        if receive is None or not receive.isConnected():
            receive = rtde_receive.RTDEReceiveInterface(robot_ip, frequency_hz)
        try:
            control = rtde_control.RTDEControlInterface(robot_ip, frequency_hz)
        except RuntimeError as e:  # the pendant in Local mode, a stopped arm: watch it, do not move it
            return None, receive, f"{e}".strip()
        return control, receive
    return connect


class URArmNode(Node):
    def __init__(self, connect=None, parameters_only=False, **node_options):
        """`connect`: () -> (control, receive); default: ur_rtde to `robot_ip`.
        `parameters_only`: declare and check the parameters, serve nothing (the stack's
        start-up check of a cell file; ur_arm itself runs in its own process)."""
        super().__init__("ur_arm", **node_options)
        p = lambda name, default, d: self.declare_parameter(name, default, d).value  # noqa: E731
        _text = lambda text: described(text, read_only=True)  # noqa: E731  (all read-only)
        _float = lambda text, low, high: float_range(text, float(low), float(high), read_only=True)  # noqa: E731
        defaults = URArmSettings()
        self.robot_ip = p("robot_ip", "", _text("IP address of the UR controller (pendant: Settings > System > Network)"))
        frequency = p("rtde_frequency_hz", -1.0, _float("RTDE frequency, Hz; -1 = the controller's (500 on e-Series)", -1.0, 500.0))
        self.frame_id = p("frame_id", "task", _text("frame of move_to_pose targets (the gravity-aligned task frame)"))
        self.base_frame_id = p("base_frame_id", "base", _text(
            "the robot base frame as the controller has it (ur_robot_driver's 'base'): flange_pose_base's frame"))
        base = p("base_xyz_yaw", [0.15, -0.45, 0.0, 0.0], _text(
            "robot base frame in the task frame: x, y, z [m], yaw [rad] (base mounted upright); "
            "the same numbers as execute's arm_base_xyz_yaw"))
        tcp = p("tcp_in_flange", [0.0, 0.0, FLANGE_TO_TCP_2F85_M, 0.0, 0.0, 0.0], _text(
            "TCP in the tool flange frame as a UR pose [x, y, z (m), rx, ry, rz (rotation vector, rad)], set on "
            "the controller with setTcp: 2F-85 pinch point 0.1558 m out; TCP y must be the fingers' closing axis"))
        ws_min = p("workspace_min_m", list(defaults.workspace_min_m), _text(
            "protective box minimum [x, y, z], task frame, m: TCP targets outside the box are refused"))
        ws_max = p("workspace_max_m", list(defaults.workspace_max_m), _text("protective box maximum [x, y, z], task frame, m"))
        settings = URArmSettings(
            X_task_base=xyz_yaw_to_matrix(base),
            tcp_in_flange=tuple(tcp),
            workspace_min_m=tuple(ws_min), workspace_max_m=tuple(ws_max),
            default_speed_mps=p("default_speed_mps", defaults.default_speed_mps, _float("TCP speed when a request gives 0, m/s", 0.001, 1.0)),
            max_speed_mps=p("max_speed_mps", defaults.max_speed_mps, _float("TCP speed cap, m/s (faster requests are capped)", 0.001, 1.0)),
            acceleration_mps2=p("acceleration_mps2", defaults.acceleration_mps2, _float("moveL tool acceleration, m/s^2", 0.01, 5.0)),
            stop_deceleration_mps2=p("stop_deceleration_mps2", defaults.stop_deceleration_mps2, _float("stopL tool deceleration, m/s^2", 0.1, 10.0)),
            call_timeout_s=p("call_timeout_s", defaults.call_timeout_s, _float("longest wait for one RTDE call; longer = lost link, s", 0.05, 60.0)),
            connect_timeout_s=p("connect_timeout_s", defaults.connect_timeout_s, _float("longest wait for connecting (uploads the control script), s", 0.1, 120.0)),
            motion_timeout_margin_s=p("motion_timeout_margin_s", defaults.motion_timeout_margin_s, _float("added to a motion's expected time before it is stopped, s", 0.0, 600.0)),
            position_tolerance_m=p("position_tolerance_m", defaults.position_tolerance_m, _float("arrived = TCP this close to the target, m", 1e-5, 0.1)),
            orientation_tolerance_deg=p("orientation_tolerance_deg", defaults.orientation_tolerance_deg, _float("arrived = TCP this well aligned, deg", 0.01, 30.0)),
            payload_kg=p("payload_kg", 0.0, _float("> 0: setPayload on connect (2F-85: 0.925 kg); 0 = keep the pendant's payload", 0.0, 20.0)),
            payload_cog_m=tuple(p("payload_cog_m", [0.0, 0.0, 0.0], _text("payload centre of gravity in the flange frame [x, y, z], m"))),
            watchdog_period_s=p("watchdog_period_s", defaults.watchdog_period_s, _float(
                "RTDE watchdog: the controller stops the arm when it hears no kick for this long (a lost link), s",
                0.05, 5.0)),
            contact_force_limit_n=p("contact_force_limit_n", defaults.contact_force_limit_n, _float(
                "stop a motion when the TCP force's magnitude rises this much above its value when the motion "
                "began, N (the sim's max_contact_force_n); 0 = off, leaving only the robot's own force limit", 0.0, 500.0)),
            tcp_check_tolerance_m=p("tcp_check_tolerance_m", defaults.tcp_check_tolerance_m, _float(
                "monitoring only: largest distance between the controller's TCP (from the joint angles) and "
                "tcp_in_flange for which flange poses are published, m", 0.0005, 0.05)),
            tcp_check_tolerance_deg=p("tcp_check_tolerance_deg", defaults.tcp_check_tolerance_deg, _float(
                "monitoring only: the same for the TCP's orientation, deg", 0.05, 10.0)),
        )
        camera = p("camera_in_flange", [0.0] * 7, _text(
            "eye-in-hand camera: its optical frame in the flange frame [x, y, z (m), qx, qy, qz, qw] as "
            "calibrate_camera writes it; all zeros = no camera on the arm (camera_pose is not published)"))
        self.X_flange_camera = None
        if any(camera):
            try:
                if len(camera) != 7:
                    raise PoseError(f"{len(camera)} values")
                self.X_flange_camera = matrix_from_pose(camera[:3], camera[3:])
            except PoseError as e:
                raise ValueError(f"camera_in_flange must be [x, y, z, qx, qy, qz, qw] with a unit quaternion, "
                                 f"got {list(camera)} ({e})") from None
        camera_in_base = p("camera_in_base", [0.0] * 7, _text(
            "eye-to-hand camera: its optical frame in the robot base frame [x, y, z (m), qx, qy, qz, qw] as "
            "calibrate_camera writes it; the stack composes tsdf.camera_pose from it; all zeros = none"))
        if any(camera) and any(camera_in_base):
            raise ValueError("camera_in_flange and camera_in_base are both set: one camera, one calibration; keep "
                             "the one calibrate_camera wrote last")
        # calibrate_camera's record of the calibration: read by people, not by the code.
        for name, default, text in (("calibration_date", "", "when calibrate_camera solved it (UTC)"),
                                    ("calibration_mode", "", "eye_to_hand or eye_in_hand"),
                                    ("calibration_views", 0, "views it used"),
                                    ("calibration_residual_mm", 0.0, "RMS spread of the views, mm"),
                                    ("calibration_residual_deg", 0.0, "RMS spread of the views, deg"),
                                    ("calibration_reprojection_px", 0.0, "RMS board reprojection, px")):
            p(name, default, _text(f"camera calibration record: {text}"))
        state_rate = p("state_rate_hz", 30.0, _float("flange_pose (and camera_pose) rate, Hz", 0.5, 250.0))
        self.reconnect_period_s = p("reconnect_period_s", 5.0, _float("retry period while the robot is unreachable, s", 0.1, 600.0))
        if connect is None:
            if not self.robot_ip:
                raise ValueError("robot_ip is empty: set it to the UR controller's address, e.g. -p robot_ip:=192.168.1.102")
            connect = rtde_connect(self.robot_ip, frequency)
        self.where = f"the UR controller at {self.robot_ip or 'the injected interfaces'}"
        self.arm = URArm(connect, settings, log=self.get_logger().info)
        self._last_problem = None
        self._last_problem_t = -math.inf
        self._last_status = None
        if parameters_only:
            return

        services = ReentrantCallbackGroup()
        self.create_service(MoveToPose, "move_to_pose", self._guarded(self._on_move), callback_group=services)
        self.create_service(Trigger, "stop_motion", self._guarded(self._on_stop), callback_group=services)
        self.create_service(Trigger, "~/reconnect", self._guarded(self._on_reconnect), callback_group=services)
        self.create_service(SetBool, "~/arm", self._guarded(self._on_arm), callback_group=services)
        self.create_subscription(Bool, "emergency_stop", self._on_estop, 10, callback_group=services)
        self.create_timer(self.reconnect_period_s, self._keep_connected, callback_group=MutuallyExclusiveCallbackGroup())
        self.pub_flange = self.create_publisher(PoseStamped, "flange_pose", 10)
        self.pub_flange_base = self.create_publisher(PoseStamped, "flange_pose_base", 10)
        self.pub_camera = (self.create_publisher(PoseStamped, "camera_pose", qos_profile_sensor_data)
                           if self.X_flange_camera is not None else None)
        self.create_timer(1.0 / state_rate, self._publish_state, callback_group=MutuallyExclusiveCallbackGroup())
        self._first = self.create_timer(0.01, self._connect_first, callback_group=MutuallyExclusiveCallbackGroup())
        self.get_logger().info(
            f"ur_arm ready: move_to_pose and stop_motion for {self.where}, targets in '{self.frame_id}', "
            f"TCP {list(np.round(settings.tcp_in_flange, 4))} in the flange, speed <= {settings.max_speed_mps} m/s, "
            f"box {list(ws_min)}..{list(ws_max)} m")

    # -- connection -----------------------------------------------------------------

    def _connect_first(self):
        self._first.cancel()
        self._keep_connected()

    def _keep_connected(self):
        try:
            status = self.arm.keep_connected()
        except ConnectionLost as e:
            self._problem(f"cannot reach {self.where}: {e}; {UNREACHABLE_HINT}; retrying every {self.reconnect_period_s:g} s")
            return
        if status and status != self._last_status:  # a monitor-only link retries: say it once
            self._last_problem = None
            self.get_logger().info(f"connected to {self.where}: {status}")
        self._last_status = status or self._last_status

    def _publish_state(self):
        if not self.arm.receiving:
            return
        unasked = self.arm.watch()  # between requests the arm must not move
        if unasked:
            self.get_logger().error(unasked)
        stamp = self.get_clock().now().to_msg()
        try:
            X_base = self.arm.flange_in_base()
        except ConnectionLost as e:
            self._problem(f"{self.where}: {e}; reconnecting every {self.reconnect_period_s:g} s")
            return
        except TCPMismatch as e:
            self._problem(str(e))
            return
        X = self.arm.settings.X_task_base @ X_base
        self.pub_flange.publish(pose_stamped_from_matrix(X, stamp, self.frame_id))
        self.pub_flange_base.publish(pose_stamped_from_matrix(X_base, stamp, self.base_frame_id))
        if self.pub_camera is not None:
            self.pub_camera.publish(pose_stamped_from_matrix(X @ self.X_flange_camera, stamp, self.frame_id))

    def _problem(self, text):
        """The same problem once a minute, a new one at once."""
        now = time.monotonic()
        if text != self._last_problem or now - self._last_problem_t > 60.0:
            self.get_logger().error(text)
            self._last_problem, self._last_problem_t = text, now

    # -- services -------------------------------------------------------------------

    def _guarded(self, handler):
        def call(request, response):
            try:
                return handler(request, response)
            except Exception as e:  # a bug: say so, keep serving
                self.get_logger().error(f"{handler.__name__}: {type(e).__name__}: {e}")
                response.success = False
                response.message = f"internal error ({type(e).__name__}: {e}); ur_arm keeps running"
                return response
        return call

    def _target(self, target):
        """4x4 X_task_tcp, or raise ValueError saying what is wrong (as the sim bridge)."""
        frame = target.header.frame_id
        if frame not in ("", self.frame_id):
            raise ValueError(f"target frame {frame!r} is unknown: give the TCP pose in {self.frame_id!r}")
        try:
            return matrix_from_pose_msg(target.pose)
        except PoseError as e:
            raise ValueError(f"target pose: {e}") from None

    def _on_move(self, request, response):
        response.joint_positions = []
        response.distance_left_m = math.nan  # nothing moved, until a motion says otherwise
        try:
            X = self._target(request.target)
            result = self.arm.move(X, float(request.speed_mps), check_only=bool(request.check_only),
                                   deadline=monotonic_deadline(request.deadline, self.get_clock()))
        except ValueError as e:
            response.reachable, response.success, response.message = False, False, f"rejected: {e}"
            return response
        except ConnectionLost as e:
            self._problem(f"{self.where}: {e}; reconnecting every {self.reconnect_period_s:g} s")
            response.reachable, response.success = False, False
            response.message = f"arm connection lost: {e}; nothing further was commanded, ur_arm reconnects"
            return response
        response.reachable, response.success = result.reachable, result.success
        response.message, response.joint_positions = result.message, result.joint_positions
        response.stopped_by_contact, response.distance_left_m = result.stopped_by_contact, result.distance_left_m
        if not request.check_only and not result.success:
            self.get_logger().warn(f"move_to_pose: {result.message}")
        return response

    def _on_stop(self, request, response):
        response.success = self.arm.stop()
        response.message = "motion stopped" if response.success else "no motion was running"
        return response

    def _on_estop(self, msg):
        if msg.data:
            halted = self.arm.latch("the emergency stop (emergency_stop topic)")
            self.get_logger().error("EMERGENCY STOP: motions refused until ~/arm is called with data: true; "
                                    + ("the running motion was halted (stopL)" if halted else "no motion was running"))

    def _on_arm(self, request, response):
        response.message = self.arm.arm(bool(request.data))
        response.success = True
        self.get_logger().info(response.message)
        return response

    def _on_reconnect(self, request, response):
        if self.arm.busy:
            response.success, response.message = False, "a motion is running: stop it first"
            return response
        try:
            response.message = f"connected: {self.arm.connect()}"
            response.success = True
        except ConnectionLost as e:
            response.success, response.message = False, f"cannot reach {self.where}: {e}; {UNREACHABLE_HINT}"
        return response

    def close(self):
        self.arm.close()


def main(args=None):
    return run_node("ur_arm", URArmNode, ValueError, threads=4, args=args)


if __name__ == "__main__":
    sys.exit(main())
