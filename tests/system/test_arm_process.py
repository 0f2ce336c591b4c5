"""The UR cell's stack runs ur_arm as a process of its own (ros/arm_process.py): killing it
mid-move is an ARM_FAULT at once that disarms the executor, the rest of the stack lives on,
a new ur_arm comes up, and after ~/arm the next grasp runs. The arm is ur_arm with the
ur_rtde stand-in (tests/support/fake_ur_arm.py), the gripper the 2F-85 emulator."""
import json
import os
import pathlib
import re
import signal
import sys
import threading
import time

import pytest
from gravgrasp_msgs.srv import ExecuteGrasp
from std_srvs.srv import SetBool

from ros_testing import BackgroundSpin, wait_until

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]
UR = ROOT / "gravgrasp_detector" / "cells" / "ur5e_2f85_realsense.yaml"
R = ExecuteGrasp.Response


def stack_with_stand_in_arm(ros_process, tmp_path, env=None):
    """The UR sample cell file, with the stand-in arm and the gripper emulator on a pty."""
    link = str(tmp_path / "ttyGripper")
    ros_process("robotiq_driver", "gripper_emulator",
                args=["--link", link, "--object-width-m", "0.05", "--activation-time-s", "0.1"])
    arm = f"{sys.executable} {ROOT / 'tests' / 'support' / 'fake_ur_arm.py'}"
    return ros_process("gravgrasp_detector", "stack", env=env, cmd=[
        str(ROOT / "ros_ws/install/gravgrasp_detector/lib/gravgrasp_detector/stack"), "--ros-args",
        "--params-file", str(UR), "-p", f"stack:arm_command:={arm}", "-p", f"execute:gripper_port:={link}",
        "-p", "execute:max_tsdf_age_s:=0.0", "-p", "execute:gripper_empty_closed_m:=0.0",
        "-p", "execute:gripper_reply_timeout_s:=0.5", "-p", "ur_arm:max_speed_mps:=0.25"])


def grasp_request():
    request = ExecuteGrasp.Request()
    request.header.frame_id = "task"
    p, q = request.grasp.pose.position, request.grasp.pose.orientation
    p.x, p.y, p.z = 0.15, 0.15, 0.08
    q.x, q.w = 1.0, 0.0  # approach straight down
    return request


def test_killing_the_arm_process_mid_move_disarms_and_a_new_one_serves(ros_process, ros_node, tmp_path):
    motions = tmp_path / "arm.jsonl"
    stack = stack_with_stand_in_arm(ros_process, tmp_path, env={"FAKE_UR_LOG": str(motions)})
    stack.wait_for_output("execute ready", timeout_s=180)
    first_pid = int(stack.wait_for_output(r"arm adapter started \(pid (\d+)\)", 30).group(1))
    stack.wait_for_output("ur_arm ready", timeout_s=60)
    spin = BackgroundSpin(ros_node)
    try:
        arm_switch = ros_node.create_client(SetBool, "execute/arm")
        assert spin.call(arm_switch, SetBool.Request(data=True), 30, resend_s=5.0).success
        execute = ros_node.create_client(ExecuteGrasp, "execute_grasp")
        result = {}
        worker = threading.Thread(target=lambda: result.setdefault("r", spin.call(execute, grasp_request(), 120)))
        worker.start()

        def moving():
            return motions.exists() and any(json.loads(line)["event"] == "motion" for line in motions.read_text().splitlines())
        assert wait_until(moving, 60), "the arm never started a motion"
        os.kill(first_pid, signal.SIGKILL)  # ur_rtde's native library crashing, as its users report
        t_kill = time.monotonic()
        worker.join(60)
        answered_s = time.monotonic() - t_kill
        r = result["r"]
        print(f"\nkilled mid-move; answered after {answered_s:.2f} s: {r.message}")
        assert r.result_code == R.ARM_FAULT and "arm adapter process" in r.message and "SIGKILL" in r.message, r.message
        assert answered_s < 5.0, "noticed only by a timeout"
        line = stack.wait_for_output(rf"the arm adapter process \(pid {first_pid}\) ended, killed by SIGKILL: [^\n]*", 10)
        print(line.group(0))
        assert "executor disarmed" in line.group(0) or "stays disarmed" in line.group(0)
        assert stack.alive(), "the stack went down with its arm adapter"
        second = stack.wait_for_output(r"arm adapter started \(pid (\d+)\); the executor stays disarmed", 30)
        assert int(second.group(1)) != first_pid
        assert wait_until(lambda: len(re.findall("ur_arm ready", stack.output())) >= 2, 60)
        refused = spin.call(execute, grasp_request(), 60)
        assert refused.result_code == R.NOT_ARMED, refused.message
        assert spin.call(arm_switch, SetBool.Request(data=True), 30).success
        again = spin.call(execute, grasp_request(), 120)
        assert again.result_code == R.SUCCESS, again.message
    finally:
        spin.shutdown()


def test_a_short_arm_soak(tmp_path):
    """`make soak-arm` for 15 s: the RTDE link dropped every 4 s, one busy process beside
    the stack; no motion outside an accepted request, no SUCCESS off its target."""
    import subprocess
    run = subprocess.run([sys.executable, str(ROOT / "tests" / "support" / "arm_soak.py"), "--duration-s", "15",
                          "--drop-every-s", "4", "--load-processes", "1", "--out", str(tmp_path / "soak")],
                         capture_output=True, text=True, timeout=240)
    lines = run.stdout.strip().splitlines()
    print("\n" + "\n".join(lines[-8:]))
    assert lines and lines[-1] == "arm_soak_ok=1", run.stdout[-3000:] + run.stderr[-3000:]
    figures = dict(line.split("=", 1) for line in lines if "=" in line and " " not in line)
    assert int(figures["link_drops"]) >= 2 and int(figures["arm_successes"]) >= 1, figures
