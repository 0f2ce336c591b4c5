"""The execute node as a real process: /execute_grasp over DDS, the gripper over Modbus
RTU (the emulator executable on a pty), the arm through MoveToPose served here.

The emulated gripper has a 50 mm object between its fingers all the time, so these
tests give the node a stored empty-closed calibration (it could not measure one with
an object in the hand) and no camera (max_tsdf_age_s 0) unless a test is about that."""
import math
import pathlib
import threading

import pytest
from gravgrasp_msgs.msg import Grasp, GraspArray, TSDFVolume
from gravgrasp_msgs.srv import ExecuteGrasp, MoveToPose
from gravgrasp_detector.ros.tsdf_node import VOLUME_QOS
from rclpy.callback_groups import ReentrantCallbackGroup
from ros_testing import BackgroundSpin, wait_until
from ros_testing import call_spun as call  # the fixture's executor spins the test node
from std_srvs.srv import SetBool

import time

import rclpy.duration

R = ExecuteGrasp.Response


def top_down_grasp(x=0.15, y=0.15, z=0.08) -> Grasp:
    g = Grasp()
    g.pose.position.x, g.pose.position.y, g.pose.position.z = x, y, z
    g.pose.orientation.x, g.pose.orientation.w = 1.0, 0.0  # TCP z (approach) points down
    g.gravity_rejection_score, g.validness = 20.0, 0.9
    return g


@pytest.fixture
def execute_params():
    """Parameters of the execute node; a test overrides them by taking this fixture."""
    return {"gripper_empty_closed_m": 0.0, "max_tsdf_age_s": 0.0}


@pytest.fixture
def stack(ros_node, ros_process, tmp_path, execute_params):
    link = str(tmp_path / "ttyGripper")
    emulator = ros_process("robotiq_driver", "gripper_emulator",
                           args=["--link", link, "--object-width-m", "0.05", "--activation-time-s", "0.1"])
    # The arm: a MoveToPose server in this process that records targets; `gate` can hold a motion.
    arm = {"targets": [], "gate": threading.Event(), "deadlines": []}
    arm["gate"].set()

    def move(request, response):
        arm["targets"].append(request.target.pose.position.z)
        arm["deadlines"].append(request.deadline.sec + request.deadline.nanosec * 1e-9)
        arm["gate"].wait(20)
        response.reachable = response.success = True
        response.message = "moved"
        return response

    arm["service"] = ros_node.create_service(MoveToPose, "move_to_pose", move, callback_group=ReentrantCallbackGroup())
    arm["serve"] = lambda: ros_node.create_service(MoveToPose, "move_to_pose", move,
                                                   callback_group=ReentrantCallbackGroup())
    execute = ros_process("gravgrasp_detector", "execute",
                          params={"gripper_port": link, "check_ik": True, "gripper_timeout_s": 5.0, **execute_params})
    execute.wait_for_output("execute ready", timeout_s=30)
    spinner = BackgroundSpin(ros_node)
    # One client per service for the whole test, each through a first round trip that is
    # safe to repeat (disarm; a grasp in a wrong frame): a reply to a just-created client
    # can be lost (rmw_fastrtps#842), and resending an execution would not be safe.
    arm_switch = ros_node.create_client(SetBool, "execute/arm")
    assert not spinner.call(arm_switch, SetBool.Request(data=False), resend_s=3.0).message.startswith("armed")
    execute_client = ros_node.create_client(ExecuteGrasp, "execute_grasp")
    warm_up = spinner.call(execute_client, execute_request(top_down_grasp(), frame="warm_up"), resend_s=3.0)
    assert warm_up.result_code == R.INVALID_REQUEST
    yield {"node": ros_node, "arm": arm, "execute": execute, "emulator": emulator,
           "arm_switch": arm_switch, "client": execute_client}
    spinner.shutdown()


def arm_executor(stack):
    assert call(stack["arm_switch"], SetBool.Request(data=True)).success


def execute_request(grasp=None, frame="task", index=None):
    request = ExecuteGrasp.Request()
    if index is not None:
        request.use_index, request.grasp_index = True, index
    else:
        request.header.frame_id, request.grasp = frame, grasp
    return request


def test_refuses_until_armed_then_executes_and_reports(stack):
    client = stack["client"]
    response = call(client, execute_request(top_down_grasp()))
    assert response.result_code == R.NOT_ARMED and "~/arm" in response.message
    assert stack["arm"]["targets"] == []

    arm_executor(stack)
    response = call(client, execute_request(top_down_grasp()))
    assert response.success and response.result_code == R.SUCCESS, response.message
    assert [round(z, 3) for z in stack["arm"]["targets"]] == [0.13, 0.08, 0.23]
    assert response.executed_grasp.gravity_rejection_score == pytest.approx(20.0)


def test_malformed_and_unknown_requests_are_invalid(stack):
    client = stack["client"]
    bad = top_down_grasp()
    bad.pose.position.x = math.nan
    assert call(client, execute_request(bad)).result_code == R.INVALID_REQUEST
    wrong_frame = call(client, execute_request(top_down_grasp(), frame="camera"))
    assert wrong_frame.result_code == R.INVALID_REQUEST and "'task'" in wrong_frame.message
    no_grasps = call(client, execute_request(index=0))
    assert no_grasps.result_code == R.INVALID_REQUEST and "out of range" in no_grasps.message
    assert stack["execute"].alive()


def test_by_index_of_latest_grasps_and_busy_while_running(stack):
    node = stack["node"]
    publisher = node.create_publisher(GraspArray, "grasps", 10)
    grasps = GraspArray()
    grasps.header.frame_id = "task"
    grasps.grasps = [top_down_grasp(0.12, 0.15), top_down_grasp(0.18, 0.15, 0.1)]
    arm_executor(stack)
    assert wait_until(lambda: publisher.get_subscription_count() > 0, 15)
    publisher.publish(grasps)
    client = stack["client"]
    # Hold the arm in its first motion, so the second call arrives mid-execution.
    stack["arm"]["gate"].clear()
    first = {}
    worker = threading.Thread(target=lambda: first.setdefault("r", call(client, execute_request(index=1), 60)))
    worker.start()
    assert wait_until(lambda: stack["arm"]["targets"] or not worker.is_alive(), 20)
    if not stack["arm"]["targets"]:
        worker.join()
        pytest.fail(f"first call did not start moving: {first['r'].message}")
    busy = call(client, execute_request(top_down_grasp()))
    assert busy.result_code == R.BUSY
    stack["arm"]["gate"].set()
    worker.join(60)
    assert first["r"].result_code == R.SUCCESS, first["r"].message
    assert stack["arm"]["targets"][1] == pytest.approx(0.1)  # grasp index 1's height


def test_unreachable_grasp_is_refused_before_moving(stack):
    arm_executor(stack)
    client = stack["client"]
    sideways_up = top_down_grasp()
    sideways_up.pose.orientation.x, sideways_up.pose.orientation.w = 0.0, 1.0  # approach pointing up
    response = call(client, execute_request(sideways_up))
    assert response.result_code == R.UNREACHABLE and "cone" in response.message
    assert stack["arm"]["targets"] == []


def test_first_feasible_walks_past_refused_grasps_of_the_latest_grasps(stack):
    """use_index + first_feasible: grasps the checks refuse (here: outside the workspace, and
    an approach pointing up) send the next-ranked one; the reply says which ran."""
    node = stack["node"]
    publisher = node.create_publisher(GraspArray, "grasps", 10)
    up = top_down_grasp(0.15, 0.15, 0.09)
    up.pose.orientation.x, up.pose.orientation.w = 0.0, 1.0
    grasps = GraspArray()
    grasps.header.frame_id = "task"
    grasps.grasps = [top_down_grasp(0.9, 0.15), up, top_down_grasp(0.18, 0.15, 0.1), top_down_grasp()]
    arm_executor(stack)
    assert wait_until(lambda: publisher.get_subscription_count() > 0, 15)
    publisher.publish(grasps)
    client = stack["client"]
    only_first = execute_request(index=0)
    assert wait_until(lambda: call(client, only_first).result_code != R.INVALID_REQUEST, 15)  # /grasps arrived
    assert call(client, only_first).result_code == R.UNREACHABLE and stack["arm"]["targets"] == []
    walk = execute_request(index=0)
    walk.first_feasible = True
    response = call(client, walk, 60)
    assert response.result_code == R.SUCCESS, response.message
    assert (response.executed_index, response.refused_before_motion) == (2, 2)
    assert response.executed_grasp.pose.position.z == pytest.approx(0.1)
    assert [round(z, 3) for z in stack["arm"]["targets"]] == [0.15, 0.1, 0.25]  # pre-grasp, grasp, lift of #3


def tsdf_volume(stamp) -> TSDFVolume:
    """An observed but empty 40^3 workspace (no surface: nothing to collide with)."""
    msg = TSDFVolume()
    msg.header.frame_id, msg.header.stamp = "task", stamp
    msg.origin.orientation.w = 1.0
    msg.voxel_size_m, msg.resolution, msg.truncation_m = 0.0075, 40, 0.03
    msg.tsdf = [0.0] * 40 ** 3
    msg.weights = [1.0] * 40 ** 3
    return msg


@pytest.mark.parametrize("execute_params", [{"gripper_empty_closed_m": 0.0, "max_tsdf_age_s": 2.0}])
def test_no_or_a_stale_tsdf_is_refused_before_moving(stack):
    """Fault matrix row 'TSDF stale': STALE_SCENE at once, nothing moves, still armed."""
    node = stack["node"]
    arm_executor(stack)
    client = stack["client"]
    none_yet = call(client, execute_request(top_down_grasp()))
    assert none_yet.result_code == R.STALE_SCENE and "no TSDF" in none_yet.message

    publisher = node.create_publisher(TSDFVolume, "tsdf", VOLUME_QOS)
    assert wait_until(lambda: publisher.get_subscription_count() > 0, 15)
    now = node.get_clock().now()
    old = (now - rclpy.duration.Duration(seconds=10.0)).to_msg()
    publisher.publish(tsdf_volume(old))
    assert wait_until(lambda: "s old" in call(client, execute_request(top_down_grasp())).message, 10)
    stale = call(client, execute_request(top_down_grasp()))
    assert stale.result_code == R.STALE_SCENE and "max_tsdf_age_s" in stale.message, stale.message
    assert stack["arm"]["targets"] == []

    publisher.publish(tsdf_volume(node.get_clock().now().to_msg()))  # the camera is back
    assert wait_until(lambda: call(client, execute_request(top_down_grasp())).result_code == R.SUCCESS, 15)


@pytest.mark.parametrize("execute_params", [{"gripper_empty_closed_m": 0.0, "max_tsdf_age_s": 0.0,
                                             "arm_service": "hanging/move_to_pose"}])
def test_arm_service_that_vanishes_mid_move_is_an_arm_fault_then_recovers(stack, ros_process):
    """Fault matrix row 'arm service disappears mid-move': an arm adapter (its own
    process) accepts the pre-grasp motion, hangs, and is stopped: ARM_FAULT about a
    second after its service left the graph (not after arm_timeout_s, 20 s), disarmed.
    With an adapter serving again and the executor re-armed, the next grasp runs."""
    import sys

    node = stack["node"]
    adapter = ros_process("tests", "hanging_arm", cmd=[sys.executable, str(pathlib.Path(__file__).resolve().parents[1] / "support" / "hanging_arm.py")],
                          remap={"move_to_pose": "hanging/move_to_pose"})
    adapter.wait_for_output("hanging_arm ready", 30)
    arm_executor(stack)
    client = stack["client"]
    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("r", call(client, execute_request(top_down_grasp()), 60)))
    worker.start()
    adapter.wait_for_output("motion accepted", 30)
    t0 = time.monotonic()
    adapter.stop()  # the adapter goes away mid-move
    worker.join(60)
    elapsed = time.monotonic() - t0
    r = result["r"]
    assert r.result_code == R.ARM_FAULT and "left the ROS graph" in r.message, r.message
    assert elapsed < 10.0, f"took {elapsed:.1f} s (arm_timeout_s is 20 s)"
    assert call(client, execute_request(top_down_grasp())).result_code == R.NOT_ARMED

    # An adapter serves again (this test's own, under the name the executor uses).
    node.create_service(MoveToPose, "hanging/move_to_pose", lambda req, res: setattr(res, "success", True) or res,
                        callback_group=ReentrantCallbackGroup())
    arm_executor(stack)
    again = call(client, execute_request(top_down_grasp()))
    assert again.result_code == R.SUCCESS, again.message


@pytest.mark.parametrize("execute_params", [{"gripper_empty_closed_m": 0.0, "max_tsdf_age_s": 0.0, "arm_timeout_s": 2.0}])
def test_a_motion_the_executor_gives_up_on_carries_its_deadline_and_is_stopped(stack):
    """Path 3 of the arm adapter's matrix: a request waits in the adapter (a reconnect)
    past the executor's timeout. The deadline travels with it, and giving up sends
    stop_motion, so the arm cannot move later for a grasp nobody waits for."""
    from std_srvs.srv import Trigger
    node, arm = stack["node"], stack["arm"]
    stops = []

    def stop(request, response):
        stops.append(time.monotonic())
        response.success = True
        return response

    node.create_service(Trigger, "stop_motion", stop, callback_group=ReentrantCallbackGroup())
    arm_executor(stack)
    arm["gate"].clear()  # the pre-grasp motion does not end
    t_ros = node.get_clock().now().nanoseconds * 1e-9
    t0 = time.monotonic()
    try:
        result = call(stack["client"], execute_request(top_down_grasp()), 30)
    finally:
        arm["gate"].set()
    assert result.result_code == R.TIMEOUT and "stop_motion sent" in result.message, result.message
    assert stops and stops[0] - t0 < 5.0, "the executor gave up without stop_motion"
    assert arm["deadlines"] and abs(arm["deadlines"][0] - (t_ros + 2.0)) < 1.0, (arm["deadlines"], t_ros)


@pytest.mark.parametrize("execute_params", [{"gripper_empty_closed_m": 0.0, "max_tsdf_age_s": 0.0,
                                             "arm_service": "hanging/move_to_pose"}])
def test_an_arm_service_that_leaves_the_graph_while_idle_disarms(stack, ros_process):
    """An arm adapter in another process that goes away between grasps (stopped, crashed,
    its node gone) disarms the armed executor, in one sentence, as its death under the
    stack does; a new adapter and ~/arm bring it back."""
    import sys

    node = stack["node"]
    adapter = ros_process("tests", "hanging_arm", cmd=[sys.executable, str(pathlib.Path(__file__).resolve().parents[1] / "support" / "hanging_arm.py")],
                          remap={"move_to_pose": "hanging/move_to_pose"})
    adapter.wait_for_output("hanging_arm ready", 30)
    stack["execute"].wait_for_output(r"arm service \S*hanging/move_to_pose is available", 15)
    arm_executor(stack)
    adapter.stop()  # goes away while the executor is armed and idle
    line = stack["execute"].wait_for_output(r"arm service \S+ left the ROS graph: executor disarmed[^\n]*", 15)
    print(f"\n{line.group(0)}")
    refused = call(stack["client"], execute_request(top_down_grasp()))
    assert refused.result_code == R.NOT_ARMED, refused.message
    node.create_service(MoveToPose, "hanging/move_to_pose", lambda req, res: setattr(res, "success", True) or res,
                        callback_group=ReentrantCallbackGroup())
    arm_executor(stack)
    assert wait_until(lambda: call(stack["client"], execute_request(top_down_grasp())).result_code == R.SUCCESS, 20)
