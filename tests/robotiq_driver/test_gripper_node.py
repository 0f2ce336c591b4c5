"""The installed gripper node (`ros2 run robotiq_driver gripper`) as a real process, talking Modbus RTU over a pty to the
2F-85 emulator and DDS to this test."""
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from gravgrasp_msgs.msg import GripperStatus
from gravgrasp_msgs.srv import MoveGripper
from std_srvs.srv import Trigger

from robotiq_driver.emulator.emulated_gripper import GripperEmulator, KinematicFingers
from robotiq_driver.emulator.pty_modbus_server import PtyModbusServer
from ros_testing import call_service, spin_until


class Listener:
    """Latest GripperStatus and DiagnosticStatus the node published."""

    def __init__(self, node):
        self.status: list[GripperStatus] = []
        self.diagnostics: list[DiagnosticStatus] = []
        node.create_subscription(GripperStatus, "/gripper/status", self.status.append, 10)
        node.create_subscription(
            DiagnosticArray, "/diagnostics", lambda m: self.diagnostics.extend(m.status), 10
        )

    def last(self) -> GripperStatus | None:
        return self.status[-1] if self.status else None


def move(node, position_m, speed_mps=0.15, force_n=40.0, wait=True):
    client = node.create_client(MoveGripper, "/gripper/move")
    request = MoveGripper.Request(position_m=position_m, speed_mps=speed_mps, force_n=force_n, wait=wait)
    return call_service(node, client, request, timeout_s=20)


def trigger(node, name):
    return call_service(node, node.create_client(Trigger, name), Trigger.Request(), timeout_s=20)


def test_node_activates_moves_and_reports_over_emulator_process(ros_node, ros_process, tmp_path):
    link = tmp_path / "ttyRobotiq"
    emulator = ros_process(
        "robotiq_driver", "gripper_emulator",
        args=["--link", link, "--object-width-m", "0.04", "--activation-time-s", "0.3"],
    )
    emulator.wait_for_output("serving on")
    ros_process("robotiq_driver", "gripper", params={"port": str(link), "status_rate_hz": 50.0})
    seen = Listener(ros_node)
    assert spin_until(ros_node, lambda: seen.last() and seen.last().activated, 20), seen.last()
    assert seen.last().connected and seen.last().position_m == pytest.approx(0.085)

    closed = move(ros_node, 0.0)
    assert closed.success, closed.message
    assert closed.message == "stopped on an object while closing, at 40.0 mm"
    assert closed.status.object_detected and closed.status.object_status == GripperStatus.OBJECT_CONTACT_CLOSING
    assert closed.status.position_m == pytest.approx(0.040, abs=0.085 / 255)
    assert closed.status.requested_counts == 255
    assert spin_until(ros_node, lambda: seen.last().object_detected, 5)

    rejected = move(ros_node, 0.09)
    assert not rejected.success and "position = 0.09 m is outside the gripper's range" in rejected.message
    rejected = move(ros_node, 0.05, speed_mps=0.5)
    assert not rejected.success and "speed = 0.5 m/s" in rejected.message

    started = move(ros_node, 0.085, speed_mps=0.02, wait=False)  # 2.25 s of travel from 40 mm
    assert started.success and started.message == "moving to 85.0 mm"
    # Stop once it has left 40 mm: under load the first status with `moving` can come before
    # the first count of travel, and a stop then leaves it at 135 counts.
    assert spin_until(ros_node, lambda: seen.last().moving and seen.last().position_counts < 135, 5), seen.last()
    assert trigger(ros_node, "/gripper/stop").success
    assert spin_until(ros_node, lambda: not seen.last().moving, 5), seen.last()
    count, stopped_at = len(seen.status), seen.last().position_counts
    assert spin_until(ros_node, lambda: len(seen.status) > count + 10, 5)
    assert {m.position_counts for m in seen.status[count:]} == {stopped_at}  # it stays put
    assert 0 < stopped_at < 135  # short of 85 mm (0 counts), past 40 mm (135 counts)

    assert trigger(ros_node, "/gripper/activate").message == "activated"
    closed = trigger(ros_node, "/gripper/close")  # default speed and force
    assert closed.success and closed.message == "stopped on an object while closing, at 40.0 mm"
    opened = trigger(ros_node, "/gripper/open")
    assert opened.success and opened.message == "reached 85.0 mm, no object"
    assert spin_until(ros_node, lambda: any(d.level == DiagnosticStatus.OK for d in seen.diagnostics), 5)


def test_node_reports_faults_and_lost_connection_then_recovers(ros_node, ros_process, tmp_path):
    emulator = GripperEmulator(KinematicFingers(), activation_time_s=0.2)
    with PtyModbusServer(emulator, link_path=str(tmp_path / "tty")) as server:
        ros_process("robotiq_driver", "gripper", params={
            "port": server.port, "status_rate_hz": 50.0, "timeout_s": 0.2, "retries": 1,
            "reconnect_period_s": 0.2,
        })
        seen = Listener(ros_node)
        assert spin_until(ros_node, lambda: seen.last() and seen.last().activated, 20)

        emulator.inject_fault(0x0E)
        assert spin_until(ros_node, lambda: seen.last().fault_code == 0x0E, 5)
        assert "overcurrent" in seen.last().fault_text
        refused = move(ros_node, 0.0)
        assert not refused.success and "0x0E" in refused.message and "overcurrent" in refused.message
        assert spin_until(ros_node, lambda: any(d.level == DiagnosticStatus.ERROR for d in seen.diagnostics), 5)
        assert trigger(ros_node, "/gripper/activate").success  # reset + activate clears it
        assert seen.last().fault_code == 0 or spin_until(ros_node, lambda: seen.last().fault_code == 0, 5)
        assert move(ros_node, 0.0).message == "reached 0.0 mm, no object"

        server.respond = False
        assert spin_until(ros_node, lambda: not seen.last().connected, 10)
        lost = move(ros_node, 0.05)
        assert not lost.success and "not connected" in lost.message
        server.respond = True
        assert spin_until(ros_node, lambda: seen.last().connected and seen.last().activated, 10)


def test_node_without_a_port_keeps_running_and_says_why(ros_node, ros_process, tmp_path):
    node = ros_process("robotiq_driver", "gripper", params={"port": str(tmp_path / "missing")})
    seen = Listener(ros_node)
    assert spin_until(ros_node, lambda: seen.diagnostics, 20)
    assert seen.last() is not None and not seen.last().connected
    assert seen.diagnostics[-1].level == DiagnosticStatus.ERROR
    assert "cannot open serial port" in seen.diagnostics[-1].message
    node.wait_for_output("cannot open serial port")
    assert node.alive()


def test_node_rejects_an_out_of_range_parameter(ros_process):
    node = ros_process("robotiq_driver", "gripper", params={"slave_id": 300})
    assert node.wait_exit(30) == 2
    assert "cannot start" in node.output() and "slave_id" in node.output()
