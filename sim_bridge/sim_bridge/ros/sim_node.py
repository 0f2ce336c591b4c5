"""``sim``: the Drake sim bridge node, the robot cell the executor drives in CI.

    ros2 run sim_bridge sim --ros-args -p n_objects:=4 -p gripper_link:=/tmp/ttyRobotiqSim

A thin ROS adapter around `sim_world.SimWorld` (see there for the physics):

| name | type | |
| --- | --- | --- |
| `depth/image` | sensor_msgs/Image | 32FC1 (m) or 16UC1 (mm), 0 = no return; reliable, keep last 1 (serves best-effort subscribers too) |
| `depth/camera_info` | sensor_msgs/CameraInfo | pinhole, no distortion; reliable, keep last 1 |
| `camera_pose` | geometry_msgs/PoseStamped | T_task_camera (optical frame) in `frame_id`; reliable, keep last 1 |
| `object_states` | gravgrasp_msgs/ObjectStates | ground truth (reliable) |
| `move_to_pose` | gravgrasp_msgs/MoveToPose | straight-line TCP motion of the arm stand-in; past its `deadline` a request is refused, a motion stopped (as `ur_arm`) |
| `load_scene` | gravgrasp_msgs/LoadScene | new scene (hand back home) |
| `set_object_mass` | gravgrasp_msgs/SetObjectMass | |
| `remove_object` | gravgrasp_msgs/RemoveObject | |
| `stop_motion` | std_srvs/Trigger | halts the running motion at once (its `move_to_pose` answers `success: false`) |
| `inject_gripper_fault` | std_srvs/Trigger | test hook: the emulated 2F-85 raises gFLT 0x0E (overcurrent), fingers stop until a reset |
| `set_gripper_silent` | std_srvs/SetBool | test hook: true = the gripper stops answering Modbus (a cut cable), false = answers again |

The gripper is not a ROS interface: a Robotiq 2F-85 register emulator answers Modbus
RTU on a pseudo-terminal linked at `gripper_link`, its fingers moved by the simulated
actuator, so the executor (or robotiq_driver's `gripper` node) talks to it exactly as to
a real gripper. Once serving, the node logs ``sim ready: gripper on <path>``.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time

import numpy as np
from gravgrasp_msgs.msg import ObjectStates
from gravgrasp_msgs.srv import LoadScene, MoveToPose, RemoveObject, SetObjectMass
from geometry_msgs.msg import PoseStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import SetBool, Trigger

from gravgrasp_detector.poses import PoseError
from gravgrasp_detector.ros.interface import (described, float_range, int_range, matrix_from_pose_msg,
                                              monotonic_deadline, pose_msg_from_matrix, run_node)
from robotiq_driver.emulator.emulated_gripper import GripperEmulator
from robotiq_driver.emulator.pty_modbus_server import PtyModbusServer

from ..physics.contact import SimSettings
from ..world import CameraSettings, RealTimeRunner, SceneConfig, SimFingerPlant, SimWorld, WorldSettings

OVERCURRENT_FAULT = 0x0E  # gFLT: a major fault, the fingers stop until a reset

CAMERA_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


class SimNode(Node):
    def __init__(self):
        super().__init__("sim")
        p = self.declare_parameter
        seed = p("seed", 0, described("seed of the procedural scene (objects and their placement)", read_only=True)).value
        n_objects = p("n_objects", 3, int_range("objects drawn for the scene", 1, 10, read_only=True)).value
        arrangement = p("arrangement", "packed", described("'packed' (upright, side by side) or 'pile' (dropped)", read_only=True)).value
        mesh_dir = p("mesh_dir", "", described("directory of URDF/OBJ objects (e.g. VGN's); '' = procedural primitives", read_only=True)).value
        mass = p("object_mass_kg", 0.0, float_range("mass of every object, kg; 0 = each object's own", 0.0, 100.0, read_only=True)).value
        cam_pos = p("camera_position", [0.15, -0.125, 0.526], described("camera optical centre [x, y, z] in the task frame, m", read_only=True)).value
        cam_target = p("camera_target", [0.15, 0.15, 0.05], described("point the camera looks at [x, y, z], task frame, m", read_only=True)).value
        width = p("image_width", 640, int_range("depth image width, px", 16, 4096, read_only=True)).value
        height = p("image_height", 480, int_range("depth image height, px", 16, 4096, read_only=True)).value
        focal = p("focal_length_px", 540.0, float_range("pinhole focal length, px", 10.0, 10000.0, read_only=True)).value
        self.rate_hz = p("publish_rate_hz", 2.0, float_range("depth, camera info, camera pose and object states rate, Hz", 0.1, 60.0, read_only=True)).value
        self.encoding = p("depth_encoding", "32FC1", described("'32FC1' (metres) or '16UC1' (millimetres), REP-118", read_only=True)).value
        self.frame_id = p("frame_id", "task", described("the task frame: camera pose, object states and move targets are in it", read_only=True)).value
        self.camera_frame_id = p("camera_frame_id", "sim_camera_optical", described("frame_id of the depth image (optical frame)", read_only=True)).value
        link = p("gripper_link", "/tmp/gravgrasp_sim_gripper", described("symlink to the pty where the emulated 2F-85 answers Modbus RTU", read_only=True)).value
        contact = p("contact_model", "hydroelastic", described("'hydroelastic' (paper) or 'point' (~3x faster, less stable)", read_only=True)).value
        dt = p("time_step_s", 2e-3, float_range("Drake time step, s", 1e-4, 1e-2, read_only=True)).value
        rt = p("real_time_rate", 1.0, float_range("upper bound of simulated s per wall s", 0.1, 10.0, read_only=True)).value
        self.default_speed = p("default_speed_mps", 0.1, float_range("TCP speed when a request gives 0, m/s", 0.001, 1.0, read_only=True)).value
        max_speed = p("max_speed_mps", 0.25, float_range("TCP speed cap, m/s", 0.001, 1.0, read_only=True)).value
        max_force = p("max_contact_force_n", 60.0, float_range("rise of the net contact force on the hand since a motion began that stops it, N", 1.0, 1000.0, read_only=True)).value
        ws_min = p("workspace_min", [-0.15, -0.15, 0.05], described("arm stand-in reach, TCP box minimum [x, y, z], m", read_only=True)).value
        ws_max = p("workspace_max", [0.45, 0.45, 0.80], described("arm stand-in reach, TCP box maximum [x, y, z], m", read_only=True)).value

        if self.encoding not in ("32FC1", "16UC1"):
            raise ValueError(f"depth_encoding {self.encoding!r}: use '32FC1' or '16UC1'")
        for name, v in (("camera_position", cam_pos), ("camera_target", cam_target),
                        ("workspace_min", ws_min), ("workspace_max", ws_max)):
            if len(v) != 3 or not all(math.isfinite(x) for x in v):
                raise ValueError(f"{name} must be 3 finite numbers [x, y, z] in metres, got {list(v)}")
        if link and os.path.exists(link) and not os.path.islink(link):
            raise ValueError(f"gripper_link {link} exists and is not a symlink; choose another path")
        settings = WorldSettings(
            contact=SimSettings(time_step_s=dt, contact_model=contact),
            camera=CameraSettings(tuple(cam_pos), tuple(cam_target), width, height, focal),
            workspace_min_m=tuple(ws_min), workspace_max_m=tuple(ws_max),
            max_speed_mps=max_speed, max_contact_force_n=max_force)
        scene = SceneConfig(seed=seed, n_objects=n_objects, arrangement=arrangement, mesh_dir=mesh_dir,
                            object_mass_kg=mass)
        self.world = SimWorld(scene, settings)
        self.get_logger().info(f"scene: {', '.join(self.world.object_names()) or 'no object'}")

        self.finger_plant = SimFingerPlant(self.world, advances_time=False)
        self.emulator = GripperEmulator(plant=self.finger_plant, initial_width_m=self.world.finger_width_m())
        self.server = PtyModbusServer(self.emulator, link_path=link or None).start()
        self.runner = RealTimeRunner(self.world, self.finger_plant, real_time_rate=rt).start()

        # Reliable (keep last 1): it serves best-effort subscribers as a camera driver does,
        # and a reliable subscriber (the demo's tsdf node) gets every frame it falls behind
        # on again. Best effort lost most 1.2 MB frames, in fragments, to a busy receiver.
        self.pub_depth = self.create_publisher(Image, "depth/image", CAMERA_QOS)
        self.pub_info = self.create_publisher(CameraInfo, "depth/camera_info", CAMERA_QOS)
        self.pub_pose = self.create_publisher(PoseStamped, "camera_pose", CAMERA_QOS)
        self.pub_states = self.create_publisher(ObjectStates, "object_states", 10)
        self._render_key = None
        self._depth = None
        self.create_timer(1.0 / self.rate_hz, self._publish_guarded, callback_group=MutuallyExclusiveCallbackGroup())
        services = ReentrantCallbackGroup()
        self.create_service(MoveToPose, "move_to_pose", self._guarded(self._on_move), callback_group=services)
        self.create_service(LoadScene, "load_scene", self._guarded(self._on_load), callback_group=services)
        self.create_service(SetObjectMass, "set_object_mass", self._guarded(self._on_set_mass), callback_group=services)
        self.create_service(RemoveObject, "remove_object", self._guarded(self._on_remove), callback_group=services)
        self.create_service(Trigger, "stop_motion", self._guarded(self._on_stop), callback_group=services)
        # Test hooks: the faults a real 2F-85 and its cable produce, for the executor's tests.
        self.create_service(Trigger, "inject_gripper_fault", self._guarded(self._on_fault), callback_group=services)
        self.create_service(SetBool, "set_gripper_silent", self._guarded(self._on_silent), callback_group=services)
        self._scene_lock = threading.Lock()
        self.get_logger().info(f"sim ready: gripper on {self.server.port}")

    def close(self):
        self.runner.stop()
        self.server.stop()
        # After SIGINT/SIGTERM the context is gone (no /rosout): say it on stdout.
        print(f"[sim] sim stopped: {self.runner.sim_s:.1f} s simulated while busy, real-time factor "
              f"{self.runner.real_time_factor():.2f} (sim s per wall s of stepping)", flush=True)

    # -- robustness: an unexpected error answers or logs; it never ends the node ---------

    def _guarded(self, handler):
        def call(request, response):
            try:
                return handler(request, response)
            except Exception as e:  # a bug or a Drake error: say so, keep serving
                self.get_logger().error(f"{handler.__name__}: {type(e).__name__}: {e}")
                response.success = False
                response.message = f"internal error ({type(e).__name__}: {e}); the sim keeps running"
                return response
        return call

    def _publish_guarded(self):
        try:
            self._publish()
        except Exception as e:
            self.get_logger().error(f"publishing failed: {type(e).__name__}: {e}", throttle_duration_sec=5.0)

    # -- camera and ground truth ------------------------------------------------------

    def _publish(self):
        if self.runner.error is not None:
            self.get_logger().error(f"simulation stopped: {self.runner.error}", throttle_duration_sec=5.0)
        stamp = self.get_clock().now().to_msg()
        states = self.world.object_states()
        # A frame costs ~0.1 s of CPU that the physics then lacks: render only for a
        # subscriber, and only after the scene moved (else republish the last frame).
        want_depth = self.pub_depth.get_subscription_count() > 0
        key = (self.world.scenes_loaded, round(self.world.time_s, 4))
        if want_depth and key != self._render_key:
            self._depth = self.world.render_depth()
            self._render_key = key
        if self._depth is None:
            k, T = self.world.intrinsics(), self.world.camera_pose()
            depth = None
        else:
            depth, k, T = self._depth
        img = Image()
        img.header.stamp, img.header.frame_id = stamp, self.camera_frame_id
        img.height, img.width, img.encoding = k.height, k.width, self.encoding
        if depth is not None:
            if self.encoding == "32FC1":
                data = depth.astype(np.float32)
            else:
                data = np.where(depth > 0, np.clip(np.round(depth * 1000.0), 1, 65535), 0).astype(np.uint16)
            img.is_bigendian = 0
            img.step = k.width * data.itemsize
            img.data = data.tobytes()
        info = CameraInfo()
        info.header = img.header
        info.height, info.width = k.height, k.width
        info.distortion_model = "plumb_bob"
        info.d = [0.0] * 5
        info.k = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0]
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        info.p = [k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        cam = PoseStamped()
        cam.header.stamp, cam.header.frame_id = stamp, self.frame_id
        cam.pose = pose_msg_from_matrix(T)
        msg = ObjectStates()
        msg.header.stamp, msg.header.frame_id = stamp, self.frame_id
        msg.sim_time_s = self.world.time_s
        for s in states:
            msg.names.append(s.name)
            msg.poses.append(pose_msg_from_matrix(s.X_task_object))
            msg.mass_kg.append(s.mass_kg)
            msg.height_above_table_m.append(s.height_above_table_m)
            msg.in_hand.append(s.in_hand)
            msg.lifted.append(s.lifted)
            msg.out_of_workspace.append(s.out_of_workspace)
            msg.grasp_mode.append(s.grasp_mode)
        self.pub_pose.publish(cam)
        self.pub_info.publish(info)
        if want_depth and depth is not None:
            self.pub_depth.publish(img)
        self.pub_states.publish(msg)

    # -- services -------------------------------------------------------------------

    def _target(self, target: PoseStamped):
        """4x4 X_task_tcp, or raise ValueError saying what is wrong with the request."""
        frame = target.header.frame_id
        if frame not in ("", self.frame_id):
            raise ValueError(f"target frame {frame!r} is unknown: give the TCP pose in {self.frame_id!r}")
        try:
            return matrix_from_pose_msg(target.pose)  # PoseError is a ValueError
        except PoseError as e:
            raise ValueError(f"target pose: {e}") from None

    def _on_move(self, request, response):
        response.joint_positions = []  # the stand-in has no joints
        response.distance_left_m = math.nan  # nothing moved, until a motion says otherwise
        try:
            X = self._target(request.target)
        except ValueError as e:
            response.reachable, response.success, response.message = False, False, f"rejected: {e}"
            return response
        speed = float(request.speed_mps)
        if not math.isfinite(speed) or speed < 0:
            response.reachable, response.success = False, False
            response.message = f"rejected: speed_mps {speed} must be >= 0 (0 = default {self.default_speed} m/s)"
            return response
        reachable, message = self.world.check_reachable(X)
        response.reachable = reachable
        if request.check_only or not reachable:
            response.success, response.message = False, message
            return response
        given_up_at = monotonic_deadline(request.deadline, self.get_clock())
        if given_up_at is not None and time.monotonic() >= given_up_at:  # as ur_arm refuses it
            response.reachable, response.success = False, False
            response.message = ("refused: the request's deadline passed before the motion started "
                                "(the caller gave up on it); nothing moved")
            return response
        motion = self.world.start_move(X, speed or self.default_speed)
        # One line per motion: what the arm stand-in was asked to do, in the order it did it.
        self.get_logger().info(f"move_to_pose: hand to {np.round(X[:3, 3], 3).tolist()} m at "
                               f"{speed or self.default_speed:.2f} m/s ({motion.duration_s:.1f} s of sim time)")
        stalled_at = time.monotonic() + motion.duration_s / 0.05 + 10.0  # even at 5% of real time
        while not motion.done.wait(timeout=0.2 if given_up_at is None
                                   else min(0.2, max(0.0, given_up_at - time.monotonic()))):
            if given_up_at is not None and time.monotonic() >= given_up_at:
                self.world.stop_motion("stopped at the request's deadline (the caller gave up on it)")
                continue  # the motion is done now, with the stop's message
            if self.runner.error is not None or time.monotonic() > stalled_at:
                why = f"the simulation stopped: {self.runner.error}" if self.runner.error else "the simulation is stalled"
                response.success, response.message = False, f"motion did not finish: {why}"
                return response
        response.success, response.message = motion.result
        response.stopped_by_contact, response.distance_left_m = motion.stopped_by_contact, motion.left_m
        return response

    def _on_fault(self, request, response):
        self.emulator.inject_fault(OVERCURRENT_FAULT)
        response.success, response.message = True, "gripper fault 0x0E (overcurrent) raised; a reset (rACT = 0) clears it"
        return response

    def _on_silent(self, request, response):
        self.server.respond = not request.data
        response.success = True
        response.message = "the gripper stops answering Modbus" if request.data else "the gripper answers again"
        return response

    def _on_stop(self, request, response):
        response.success = self.world.stop_motion()
        response.message = "motion stopped" if response.success else "no motion was running"
        return response

    def _on_load(self, request, response):
        cfg = SceneConfig(seed=int(request.seed), n_objects=int(request.n_objects),
                          arrangement=request.arrangement or "packed", mesh_dir=request.mesh_dir,
                          object_mass_kg=float(request.object_mass_kg))
        try:
            with self._scene_lock:
                names = self.world.reset(cfg)
                if self.runner.error is not None:  # a new world: step it again
                    self.get_logger().warn(f"restarting the simulation thread after: {self.runner.error}")
                    self.runner.stop()
                    self.runner = RealTimeRunner(self.world, self.finger_plant,
                                                 real_time_rate=self.runner.real_time_rate).start()
        except Exception as e:  # bad request or unreadable objects: keep the current scene
            response.success, response.message = False, f"scene not loaded ({type(e).__name__}: {e}); the previous scene stays"
            return response
        response.success, response.object_names = True, names
        response.message = f"loaded {len(names)} objects"
        self.get_logger().info(f"scene: {', '.join(names) or 'no object'}")
        return response

    def _on_set_mass(self, request, response):
        try:
            self.world.set_object_mass(request.name, float(request.mass_kg))
        except (KeyError, ValueError) as e:
            response.success, response.message = False, str(e).strip("'\"")
            return response
        response.success, response.message = True, f"mass of {request.name or 'every object'} = {request.mass_kg} kg"
        return response

    def _on_remove(self, request, response):
        try:
            self.world.remove_object(request.name)
        except KeyError as e:
            response.success, response.message = False, str(e).strip("'\"")
            return response
        response.success, response.message = True, f"removed {request.name}"
        return response


def main(args=None):
    return run_node("sim", SimNode, (ValueError, OSError, RuntimeError), threads=4, args=args)


if __name__ == "__main__":
    sys.exit(main())
