"""gripper_cli (the tool for a person at the robot) against the emulator on a pty."""
import gc
import subprocess
import time

import pytest

from robotiq_driver import gripper_cli
from robotiq_driver.emulator.emulated_gripper import GripperEmulator, KinematicFingers
from robotiq_driver.emulator.pty_modbus_server import PtyModbusServer
from ros_testing import executable


@pytest.fixture
def server(tmp_path):
    emulator = GripperEmulator(KinematicFingers(object_width_m=0.040), activation_time_s=0.2)
    with PtyModbusServer(emulator, link_path=str(tmp_path / "ttyRobotiq")) as srv:
        yield srv


def cli(capsys, *argv):
    """Run the tool in this process: (exit code, stdout, stderr)."""
    # Earlier tests in this process leave rclpy futures behind; asyncio reports one
    # that failed on stderr when it is garbage-collected, which must not land in the
    # tool's output: collect them now and drop what that printed.
    gc.collect()
    capsys.readouterr()
    code = 0
    try:
        gripper_cli.main([str(a) for a in argv])
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out.strip(), err.strip()


def test_activate_close_move_open_status(server, capsys):
    port = ("--port", server.port)
    code, out, err = cli(capsys, "status", *port)
    assert code == 0 and "not activated (in reset)" in out and "fault: none" in out
    code, out, err = cli(capsys, "close", *port)
    assert code == 1 and out == ""
    assert err.startswith("gripper_cli: error: gripper not activated") and "activate it first" in err
    assert len(err.splitlines()) == 1

    assert cli(capsys, "activate", *port) == (0, "activated, opening 85.0 mm", "")
    assert cli(capsys, "close", *port, "--speed-mps", 0.15) == (
        0, "stopped on an object while closing, at 40.0 mm", "")
    assert cli(capsys, "move", "--position-m", 0.06, *port) == (0, "reached 60.0 mm, no object", "")
    # Connection options go before or after the command.
    assert cli(capsys, *port, "open", "--speed-mps", 0.15, "--force-n", 100) == (0, "reached 85.0 mm, no object", "")
    code, out, _ = cli(capsys, *port, "--slave-id", 9, "status")
    assert code == 0 and "slave 9: activated (gACT 1, gSTA 3, gGTO 1)" in out
    assert "opening 85.0 mm (0 counts; requested 0 counts)" in out
    assert "object: at the requested position, no object (gOBJ 3)" in out


def test_out_of_range_requests_are_refused_before_the_wire(server, capsys):
    served = server.requests_served
    code, _, err = cli(capsys, "move", "--position-m", 0.2, "--port", server.port)
    assert code == 1 and "position = 0.2 m is outside the gripper's range" in err
    code, _, err = cli(capsys, "close", "--force-n", 500, "--port", server.port)
    assert code == 1 and "force = 500" in err
    assert server.requests_served == served


def test_a_fault_is_one_clear_line(server, capsys):
    assert cli(capsys, "activate", "--port", server.port)[0] == 0
    server.device.inject_fault(0x0E)
    code, out, _ = cli(capsys, "status", "--port", server.port)
    assert code == 0 and "fault: 0x0E overcurrent" in out
    code, _, err = cli(capsys, "close", "--port", server.port)
    assert code == 1 and "0x0E" in err and "overcurrent" in err and len(err.splitlines()) == 1
    assert cli(capsys, "activate", "--port", server.port)[1] == "activated, opening 85.0 mm"  # reset clears it


def test_a_silent_gripper_or_a_missing_port_fail_fast(server, capsys, tmp_path):
    server.respond = False
    start = time.monotonic()
    code, _, err = cli(capsys, "status", "--port", server.port, "--timeout-s", 0.1, "--retries", 1)
    assert code == 1 and "no answer from slave 9" in err and len(err.splitlines()) == 1
    # 2 tries x 0.1 s; pymodbus' own default (3 s x 3 tries) would take 9 s. The rest of the
    # bound is room for a CI machine running two test files at once.
    assert time.monotonic() - start < 2.0
    code, _, err = cli(capsys, "status", "--port", tmp_path / "ttyUSB7")
    assert code == 1 and "cannot open serial port" in err and "dialout" in err


def test_the_installed_executable(server):
    exe = str(executable("robotiq_driver", "gripper_cli"))
    run = subprocess.run([exe, "activate", "--port", server.port], capture_output=True, text=True, timeout=30)
    assert run.returncode == 0 and run.stdout.strip() == "activated, opening 85.0 mm", run.stderr
    run = subprocess.run([exe, "move", "--port", server.port], capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and "--position-m" in run.stderr


def test_calibrate_prints_where_empty_fingers_stop(tmp_path, capsys):
    """A unit whose fingertips meet at 3.7 mm and report an object there."""
    emulator = GripperEmulator(KinematicFingers(fingers_meet_m=0.0037), activation_time_s=0.05)
    with PtyModbusServer(emulator, link_path=str(tmp_path / "ttyRobotiq")) as srv:
        assert cli(capsys, "activate", "--port", srv.port)[0] == 0
        code, out, err = cli(capsys, "calibrate", "--port", srv.port)
        assert code == 0, err
        assert "fingers close on nothing at 3.7 mm" in out and "gOBJ 2" in out
        assert "gripper_empty_closed_m:=0.0037" in out or "gripper_empty_closed_m:=0.0036" in out
        assert emulator.width_m == pytest.approx(0.085)  # left open
        emulator.plant.object_width_m = 0.04  # something in the hand: refused
        code, out, err = cli(capsys, "calibrate", "--port", srv.port)
        assert code == 1 and "something is between" in err
