"""The execute node as a real process: /execute_grasp over DDS, the gripper over Modbus
RTU (the emulator executable on a pty), the arm through MoveToPose served here."""
import math
import threading

import pytest
from gravgrasp_msgs.msg import Grasp, GraspArray
from gravgrasp_msgs.srv import ExecuteGrasp, MoveToPose
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from std_srvs.srv import SetBool

import time

R = ExecuteGrasp.Response


def wait_until(predicate, timeout_s):
    """The test node spins in a background executor here, so wait without spinning."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not predicate():
        time.sleep(0.02)
    return predicate()


def top_down_grasp(x=0.15, y=0.15, z=0.08) -> Grasp:
    g = Grasp()
    g.pose.position.x, g.pose.position.y, g.pose.position.z = x, y, z
    g.pose.orientation.x, g.pose.orientation.w = 1.0, 0.0  # TCP z (approach) points down
    g.gravity_rejection_score, g.validness = 20.0, 0.9
    return g


@pytest.fixture
def stack(ros_node, ros_process, tmp_path):
    link = str(tmp_path / "ttyGripper")
    emulator = ros_process("robotiq_driver", "gripper_emulator",
                           args=["--link", link, "--object-width-m", "0.05", "--activation-time-s", "0.1"])
    # The arm: a MoveToPose server in this process that records targets; `gate` can hold a motion.
    arm = {"targets": [], "gate": threading.Event()}
    arm["gate"].set()

    def move(request, response):
        arm["targets"].append(request.target.pose.position.z)
        arm["gate"].wait(20)
        response.reachable = response.success = True
        response.message = "moved"
        return response

    ros_node.create_service(MoveToPose, "move_to_pose", move, callback_group=ReentrantCallbackGroup())
    execute = ros_process("gravgrasp_detector", "execute",
                          params={"gripper_port": link, "check_ik": True, "gripper_timeout_s": 5.0})
    execute.wait_for_output("execute ready", timeout_s=30)
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(ros_node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    yield {"node": ros_node, "arm": arm, "execute": execute, "emulator": emulator}
    executor.shutdown()


def call(node, client, request, timeout_s=30.0):
    assert client.wait_for_service(timeout_sec=15)
    done = threading.Event()
    future = client.call_async(request)
    future.add_done_callback(lambda _: done.set())
    assert done.wait(timeout_s), f"{client.srv_name} did not answer in {timeout_s} s"
    return future.result()


def execute_request(grasp=None, frame="task", index=None):
    request = ExecuteGrasp.Request()
    if index is not None:
        request.use_index, request.grasp_index = True, index
    else:
        request.header.frame_id, request.grasp = frame, grasp
    return request


def test_refuses_until_armed_then_executes_and_reports(stack):
    node = stack["node"]
    client = node.create_client(ExecuteGrasp, "execute_grasp")
    response = call(node, client, execute_request(top_down_grasp()))
    assert response.result_code == R.NOT_ARMED and "~/arm" in response.message
    assert stack["arm"]["targets"] == []

    arm = node.create_client(SetBool, "execute/arm")
    assert call(node, arm, SetBool.Request(data=True)).success
    response = call(node, client, execute_request(top_down_grasp()))
    assert response.success and response.result_code == R.SUCCESS, response.message
    assert [round(z, 3) for z in stack["arm"]["targets"]] == [0.13, 0.08, 0.23]
    assert response.executed_grasp.gravity_rejection_score == pytest.approx(20.0)


def test_malformed_and_unknown_requests_are_invalid(stack):
    node = stack["node"]
    client = node.create_client(ExecuteGrasp, "execute_grasp")
    bad = top_down_grasp()
    bad.pose.position.x = math.nan
    assert call(node, client, execute_request(bad)).result_code == R.INVALID_REQUEST
    wrong_frame = call(node, client, execute_request(top_down_grasp(), frame="camera"))
    assert wrong_frame.result_code == R.INVALID_REQUEST and "'task'" in wrong_frame.message
    no_grasps = call(node, client, execute_request(index=0))
    assert no_grasps.result_code == R.INVALID_REQUEST and "out of range" in no_grasps.message
    assert stack["execute"].alive()


def test_by_index_of_latest_grasps_and_busy_while_running(stack):
    node = stack["node"]
    publisher = node.create_publisher(GraspArray, "grasps", 10)
    grasps = GraspArray()
    grasps.header.frame_id = "task"
    grasps.grasps = [top_down_grasp(0.12, 0.15), top_down_grasp(0.18, 0.15, 0.1)]
    call(node, node.create_client(SetBool, "execute/arm"), SetBool.Request(data=True))
    assert wait_until(lambda: publisher.get_subscription_count() > 0, 15)
    publisher.publish(grasps)
    client = node.create_client(ExecuteGrasp, "execute_grasp")
    # Hold the arm in its first motion, so the second call arrives mid-execution.
    stack["arm"]["gate"].clear()
    first = {}
    worker = threading.Thread(target=lambda: first.setdefault("r", call(node, client, execute_request(index=1), 60)))
    worker.start()
    assert wait_until(lambda: stack["arm"]["targets"] or not worker.is_alive(), 20)
    if not stack["arm"]["targets"]:
        worker.join()
        pytest.fail(f"first call did not start moving: {first['r'].message}")
    busy = call(node, client, execute_request(top_down_grasp()))
    assert busy.result_code == R.BUSY
    stack["arm"]["gate"].set()
    worker.join(60)
    assert first["r"].result_code == R.SUCCESS, first["r"].message
    assert stack["arm"]["targets"][1] == pytest.approx(0.1)  # grasp index 1's height


def test_unreachable_grasp_is_refused_before_moving(stack):
    node = stack["node"]
    call(node, node.create_client(SetBool, "execute/arm"), SetBool.Request(data=True))
    client = node.create_client(ExecuteGrasp, "execute_grasp")
    sideways_up = top_down_grasp()
    sideways_up.pose.orientation.x, sideways_up.pose.orientation.w = 0.0, 1.0  # approach pointing up
    response = call(node, client, execute_request(sideways_up))
    assert response.result_code == R.UNREACHABLE and "cone" in response.message
    assert stack["arm"]["targets"] == []
