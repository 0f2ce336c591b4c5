"""`ros2 run gravgrasp_detector execute`: serves /execute_grasp.

A thin adapter around execution.executor.GraspExecutor: it keeps the latest /grasps and
TSDF volume, reaches the arm through the MoveToPose service (`move_to_pose`, served
by the sim bridge or a real arm's adapter) and the Robotiq 2F-85 through its serial
port (robotiq_driver, Modbus RTU).

Safety, because this node moves a real arm: it starts disarmed and refuses motion
until `~/arm` (std_srvs/SetBool true); any gripper fault or timeout disarms it; a
`true` on `emergency_stop` (std_msgs/Bool) disarms at once, stops the gripper, and
aborts the running execution at its next step. Speed, force and workspace limits are
parameters no request can exceed.
"""
from __future__ import annotations

import sys
import threading
import time

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.duration import Duration
from rclpy.node import Node
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from gravgrasp_msgs.msg import GraspArray, TSDFVolume
from gravgrasp_msgs.srv import ExecuteGrasp, MoveToPose
from robotiq_driver.gripper_client import Robotiq2F85

from ..execution.executor import (Abort, ArmMotion, ArmTimeout, ArmUnavailable, ExecutionLimits, GraspExecutor,
                                  ResultCode, pose_to_matrix)
from ..execution.reachability import DEFAULT_TCP_OFFSET_M, ArmReachability
from .interface import described, pose_msg_from_matrix, run_node
from .tsdf_node import VOLUME_QOS


class ServiceArm:
    """execution.executor.Arm over the MoveToPose service. A service that leaves the ROS
    graph during a move (the adapter crashed or was stopped) raises ArmUnavailable once
    it has been gone for `gone_s`, instead of waiting out the whole motion timeout. The
    request carries its deadline (now + the motion's timeout), and giving up on it calls
    stop_motion too: the arm must not move later for a request nobody waits for."""

    POLL_S = 0.1

    def __init__(self, node: Node, service: str, stop_service: str, frame_id: str, gone_s: float = 1.0):
        self.node, self.frame_id, self.gone_s = node, frame_id, gone_s
        self.deaths = 0          # the supervised adapter process exited this many times
        self.death = ""          # how, the last time
        self.probe = False       # a new adapter process: make sure it hears us before a motion
        self.client = node.create_client(MoveToPose, service, callback_group=ReentrantCallbackGroup())
        self.stop_client = node.create_client(Trigger, stop_service, callback_group=ReentrantCallbackGroup())

    def stop(self) -> bool:
        """Ask the arm to halt now (fire and forget: an e-stop must not wait)."""
        if not self.stop_client.service_is_ready():
            return False
        self.stop_client.call_async(Trigger.Request())
        return True

    def _probe(self, X_task_tcp, timeout_s):
        """A new adapter process: its service is in the graph before it is matched to this
        client (and the dead one's stays there until its lease ends), so a motion request
        could be lost. Ask check_only (moves nothing, safe to resend) until it answers."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            request = MoveToPose.Request(speed_mps=0.0, check_only=True)
            request.target.header.frame_id = self.frame_id
            pose_msg_from_matrix(X_task_tcp, request.target.pose)
            done = threading.Event()
            future = self.client.call_async(request)
            future.add_done_callback(lambda _: done.set())
            if done.wait(min(1.0, max(0.0, deadline - time.monotonic()))):
                self.probe = False
                return
            future.cancel()
        raise ArmTimeout(f"the new arm adapter did not answer on {self.client.srv_name} within {timeout_s:.0f} s")

    def move_to(self, X_task_tcp, speed_mps, timeout_s):
        if not self.client.wait_for_service(timeout_sec=min(timeout_s, 5.0)):
            raise ArmTimeout(f"arm service {self.client.srv_name} is not available")
        if self.probe:
            self._probe(X_task_tcp, timeout_s)
        request = MoveToPose.Request(speed_mps=float(speed_mps), check_only=False)
        request.deadline = (self.node.get_clock().now() + Duration(seconds=float(timeout_s))).to_msg()
        request.target.header.frame_id = self.frame_id
        pose_msg_from_matrix(X_task_tcp, request.target.pose)
        done = threading.Event()
        future = self.client.call_async(request)
        future.add_done_callback(lambda _: done.set())
        deadline = time.monotonic() + timeout_s
        gone_since = None
        deaths = self.deaths
        while not done.wait(min(self.POLL_S, max(0.0, deadline - time.monotonic()))):
            now = time.monotonic()
            if self.deaths != deaths:
                future.cancel()
                raise ArmUnavailable(f"the arm adapter process {self.death} during the motion")
            if now >= deadline:
                future.cancel()
                self.stop()
                raise ArmTimeout(f"arm motion timed out after {timeout_s:.0f} s; stop_motion sent")
            if self.client.service_is_ready():
                gone_since = None
            elif gone_since is None:
                gone_since = now
            elif now - gone_since >= self.gone_s:
                future.cancel()
                self.stop()  # a service back under the same name (a restarted adapter) must not go on
                raise ArmUnavailable(f"service {self.client.srv_name} left the ROS graph "
                                     f"{now - gone_since:.1f} s ago without answering")
        response = future.result()
        return ArmMotion(bool(response.success), response.message, bool(response.stopped_by_contact),
                         float(response.distance_left_m))


class ExecuteNode(Node):
    def __init__(self):
        super().__init__("execute")

        def param(name, default, description):
            return self.declare_parameter(name, default, described(description)).value

        self.task_frame = param("task_frame", "task", "frame grasps must be expressed in (gravity-aligned)")
        port = param("gripper_port", "/dev/ttyUSB0", "serial port of the Robotiq 2F-85 (Modbus RTU)")
        slave_id = param("gripper_slave_id", 9, "Modbus slave id of the gripper")
        baud = param("gripper_baud", 115200, "serial baud rate")
        reply_timeout = param("gripper_reply_timeout_s", 0.1,
                              "answer timeout per Modbus attempt [s]; raise it for slow USB adapters or a "
                              "simulated gripper on a loaded machine")
        arm_service = param("arm_service", "move_to_pose", "MoveToPose service of the arm adapter or sim bridge")
        arm_stop_service = param("arm_stop_service", "stop_motion",
                                 "std_srvs/Trigger service that halts the arm at once (called on emergency stop)")
        base = param("arm_base_xyz_yaw", [0.15, -0.45, 0.0, 0.0],
                     "arm base pose in the task frame: x, y, z [m], yaw [rad] (UR5e kinematic model)")
        self.check_ik = param("check_ik", True, "check reachability with the arm's kinematic model")
        tcp_offset = param("tcp_offset_m", DEFAULT_TCP_OFFSET_M, "tool flange -> TCP distance along the flange z [m]")
        defaults = ExecutionLimits()
        limits = ExecutionLimits(
            workspace_min_m=tuple(param("workspace_min_m", list(defaults.workspace_min_m), "TCP box min, task frame [m]")),
            workspace_max_m=tuple(param("workspace_max_m", list(defaults.workspace_max_m), "TCP box max, task frame [m]")),
            approach_cone_deg=param("approach_cone_deg", defaults.approach_cone_deg,
                                    "max angle between the approach and straight down [deg]"),
            max_speed_mps=param("max_speed_mps", defaults.max_speed_mps, "arm TCP speed limit [m/s]"),
            approach_speed_mps=param("approach_speed_mps", defaults.approach_speed_mps,
                                     "pre-grasp -> grasp speed, and backing out [m/s]"),
            approach_fast_speed_mps=param("approach_fast_speed_mps", defaults.approach_fast_speed_mps,
                                          "pre-grasp -> approach_slow_last_m short of the grasp at this speed, "
                                          "the rest at approach_speed_mps [m/s] (0: all of it slow)"),
            approach_slow_last_m=param("approach_slow_last_m", defaults.approach_slow_last_m,
                                       "the last part of the approach at approach_speed_mps [m]"),
            lift_speed_mps=param("lift_speed_mps", defaults.lift_speed_mps,
                                 "grasp -> lift speed with the object in the hand [m/s]"),
            max_force_n=param("max_force_n", defaults.max_force_n, "gripper force limit [N]"),
            grip_force_n=param("grip_force_n", defaults.grip_force_n, "gripper closing force [N] (paper: 40)"),
            grip_speed_mps=param("grip_speed_mps", defaults.grip_speed_mps, "gripper closing speed [m/s]"),
            pregrasp_distance_m=param("pregrasp_distance_m", defaults.pregrasp_distance_m,
                                      "default stand-off of the pre-grasp pose [m]"),
            lift_height_m=param("lift_height_m", defaults.lift_height_m, "lift after closing [m]"),
            gripper_timeout_s=param("gripper_timeout_s", defaults.gripper_timeout_s, "per gripper motion [s]"),
            arm_timeout_s=param("arm_timeout_s", defaults.arm_timeout_s, "per arm motion [s]"),
            min_object_width_m=param("min_object_width_m", defaults.min_object_width_m,
                                     "held = gOBJ 2 and an opening at least this much wider than the "
                                     "empty-closed calibration [m]"),
            close_on_contact_within_m=param(
                "close_on_contact_within_m", defaults.close_on_contact_within_m,
                "guarded approach: an approach the arm's contact stop halts at most this far short of the grasp "
                "closes there (1 mm backed off) instead of backing out [m]; 0: off. Needs an arm whose "
                "MoveToPose answers distance_left_m (the sim bridge, ur_arm)"),
        )
        empty_closed = param("gripper_empty_closed_m", -1.0,
                             "opening where this gripper's fingers stop closing on nothing [m], as measured "
                             "with gripper_cli calibrate; negative: measure it on every connection")
        limits.empty_closed_width_m = None if empty_closed < 0 else float(empty_closed)
        table_z = float(param(
            "table_z_m", -1.0, "table top in the task frame [m] (0.0 on a cell whose task origin is on the table): "
                               "refuse grasps whose fingertips, closing in parallel onto what the TSDF shows "
                               "between the pads, would reach below it; conservative for power grasps (it "
                               "refused half of the power labels simulation passed); -1.0 or lower: off"))
        limits.table_z_m = None if table_z <= -1.0 else table_z
        self.max_tsdf_age_s = param("max_tsdf_age_s", 5.0,
                                    "refuse a grasp (STALE_SCENE) when the latest TSDF is older than this [s] "
                                    "or none arrived; 0: no TSDF needed (no collision check without one)")
        X_task_base = np.eye(4)
        c, s = np.cos(base[3]), np.sin(base[3])
        X_task_base[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
        X_task_base[:3, 3] = base[:3]
        reach = ArmReachability(X_task_base, tcp_offset_m=tcp_offset) if self.check_ik else None

        def gripper():
            return Robotiq2F85(port, slave_id=slave_id, baudrate=baud, timeout_s=reply_timeout)

        self.arm = ServiceArm(self, arm_service, arm_stop_service, self.task_frame)
        self.executor_core = GraspExecutor(self.arm, gripper, limits,
                                           reachability=reach, log=self.get_logger().info)
        if param("armed_at_start", False, "start armed (only for simulation)"):
            self.executor_core.arm_motion(True)
        self.latest_grasps = None
        self.latest_tsdf = None
        self._arm_seen = False
        self.create_timer(1.0, self._watch_arm_service, callback_group=MutuallyExclusiveCallbackGroup())
        state = MutuallyExclusiveCallbackGroup()
        self.create_subscription(GraspArray, "grasps", self._on_grasps, 10, callback_group=state)
        self.create_subscription(TSDFVolume, "tsdf", self._on_tsdf, VOLUME_QOS, callback_group=state)
        self.create_subscription(Bool, "emergency_stop", self._on_estop, 10, callback_group=ReentrantCallbackGroup())
        self.create_service(ExecuteGrasp, "execute_grasp", self._on_execute, callback_group=ReentrantCallbackGroup())
        self.create_service(SetBool, "~/arm", self._on_arm, callback_group=ReentrantCallbackGroup())
        self.get_logger().info(f"execute ready: gripper on {port}, arm via {arm_service}, "
                               f"{'armed' if self.executor_core.armed else 'disarmed (call ~/arm)'}")
        if limits.empty_closed_width_m is not None:
            self.get_logger().info(f"gripper empty-closed opening: {limits.empty_closed_width_m * 1e3:.1f} mm (stored)")

    def arm_started(self, pid: int):
        """The stack started the arm adapter process (again)."""
        self.arm.probe = self.arm.deaths > 0
        self.get_logger().info(f"arm adapter started (pid {pid})"
                               + ("; the executor stays disarmed until ~/arm" if self.arm.deaths else ""))

    def arm_exited(self, pid: int, how: str):
        """The supervised arm adapter process ended: a fault that disarms, said in one sentence."""
        self.arm.death = f"(pid {pid}) ended, {how},"
        self.arm.deaths += 1
        was = self.executor_core.armed
        self.executor_core.armed = False
        self.get_logger().error(f"the arm adapter process (pid {pid}) ended, {how}: executor "
                                f"{'disarmed' if was else 'stays disarmed'}; the stack starts it again, then call "
                                "~/arm once the arm is checked")

    def _watch_arm_service(self):
        """An adapter in another process that leaves the ROS graph while the executor is
        armed (stopped, crashed, its node gone) disarms it, as its death under the stack does."""
        ready = self.arm.client.service_is_ready()
        if self._arm_seen and not ready and self.executor_core.armed and not self.executor_core._busy.locked():
            self.executor_core.armed = False
            self.get_logger().error(f"arm service {self.arm.client.srv_name} left the ROS graph: executor disarmed; "
                                    "check the arm adapter, then call ~/arm")
        if ready and not self._arm_seen:
            self.get_logger().info(f"arm service {self.arm.client.srv_name} is available")
        self._arm_seen = ready

    def _on_grasps(self, msg):
        self.latest_grasps = msg

    def _on_tsdf(self, msg):
        self.latest_tsdf = msg

    def _on_estop(self, msg):
        if msg.data:
            self.executor_core.estop()
            halted = self.arm.stop()
            self.get_logger().error("EMERGENCY STOP: executor disarmed, gripper stopped, "
                                    + ("arm halt requested" if halted else "arm stop service NOT available"))

    def _on_arm(self, request, response):
        if request.data and self.executor_core.estopped.is_set():
            self.get_logger().warn("arming after an emergency stop")
        response.message = self.executor_core.arm_motion(request.data)
        response.success = True
        self.get_logger().info(response.message)
        return response

    def _tsdf_arrays(self):
        msg = self.latest_tsdf
        if self.max_tsdf_age_s > 0:
            if msg is None:
                raise Abort(ResultCode.STALE_SCENE, "no TSDF received yet: the collision check needs a current view; "
                                                    "check the camera and the tsdf node")
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            age = self.get_clock().now().nanoseconds * 1e-9 - stamp
            if age > self.max_tsdf_age_s:
                raise Abort(ResultCode.STALE_SCENE,
                            f"the latest TSDF is {age:.1f} s old (max_tsdf_age_s {self.max_tsdf_age_s:g}): the view "
                            "may not show the scene as it is; check the camera and the tsdf node")
        if msg is None:
            return None
        r = int(msg.resolution)
        o = msg.origin.position
        return np.asarray(msg.tsdf, np.float32).reshape(r, r, r), float(msg.voxel_size_m), np.array([o.x, o.y, o.z])

    def _on_execute(self, request, response):
        t0 = time.monotonic()
        try:
            outcome, grasp, index, refused = self._run(request)
            response.executed_grasp = grasp
            response.executed_index, response.refused_before_motion = index, refused
        except Abort as abort:
            outcome = abort.outcome
        response.success = outcome.success
        response.result_code = int(outcome.code)
        response.message = outcome.message
        which = (f" on grasp #{response.executed_index + 1} ({response.refused_before_motion} refused before it)"
                 if request.use_index and request.first_feasible else "")
        text = f"execute_grasp: {outcome.code.name}{which} in {time.monotonic() - t0:.1f} s: {outcome.message}"
        # rclpy refuses two severities from one call site, hence two lines.
        if outcome.success:
            self.get_logger().info(text)
        else:
            self.get_logger().warn(text)
        return response

    def _run(self, request):
        self.executor_core.refuse_if_estopped("execute a grasp")  # before the view's age, too
        if request.use_index:
            grasps = self.latest_grasps
            if grasps is None or request.grasp_index >= len(grasps.grasps):
                have = 0 if grasps is None else len(grasps.grasps)
                raise Abort(ResultCode.INVALID_REQUEST,
                            f"grasp index {request.grasp_index} is out of range: the latest /grasps has {have}")
            first = request.grasp_index
            candidates = grasps.grasps[first:] if request.first_feasible else [grasps.grasps[first]]
            frame = grasps.header.frame_id
        else:
            first, candidates, frame = 0, [request.grasp], request.header.frame_id
        if frame != self.task_frame:
            raise Abort(ResultCode.INVALID_REQUEST,
                        f"grasp is in frame {frame!r}; this executor takes grasps in {self.task_frame!r}")
        poses = []
        for grasp in candidates:
            p, q = grasp.pose.position, grasp.pose.orientation
            poses.append((pose_to_matrix([p.x, p.y, p.z], [q.x, q.y, q.z, q.w]), float(grasp.pregrasp_distance_m)))
        outcome, i = self.executor_core.execute_first_feasible(poses, self._tsdf_arrays())
        return outcome, candidates[i], first + i, i  # i grasps were refused before it


    def close(self):
        if self.executor_core.gripper is not None:
            self.executor_core.gripper.close()


def main(args=None):
    # Any constructor error is a bad configuration here (a gripper port that cannot be
    # opened raises OSError, a bad limit ValueError, ...): one line, exit 2.
    return run_node("execute", ExecuteNode, Exception, threads=4, args=args)


if __name__ == "__main__":
    sys.exit(main())
