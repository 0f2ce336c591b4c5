"""The 2F-85 driver against the register emulator, exchanging real Modbus RTU frames
over a pseudo-terminal (pymodbus's client in the driver, pymodbus's serial server in
the emulator), with the line's faults injected between them."""
import os
import time

import pytest
import serial

from robotiq_driver.emulator.emulated_gripper import GripperEmulator, KinematicFingers
from robotiq_driver.emulator.pty_modbus_server import PtyModbusServer
from robotiq_driver.gripper_client import (
    GripperConnectionError,
    GripperFault,
    GripperLinkError,
    GripperNotReady,
    GripperTimeout,
    Robotiq2F85,
)
from robotiq_driver.gripper_registers import COMMAND_ADDRESS, STATUS_ADDRESS, GripperState, ObjectStatus
from robotiq_driver.modbus_client import ILLEGAL_DATA_ADDRESS, ModbusConnectionError, ModbusTimeout


@pytest.fixture
def emulator():
    return GripperEmulator(KinematicFingers(object_width_m=0.040), activation_time_s=0.2)


@pytest.fixture
def server(emulator, tmp_path):
    with PtyModbusServer(emulator, link_path=str(tmp_path / "ttyRobotiq")) as srv:
        yield srv


@pytest.fixture
def gripper(server):
    with Robotiq2F85(server.port, timeout_s=0.2) as g:
        yield g


def test_activate_then_close_on_an_object_over_the_wire(gripper, emulator):
    state = gripper.activate(timeout_s=3.0)
    assert state.ready and gripper.width_m(state) == pytest.approx(0.085)
    start = time.monotonic()
    final = gripper.move_and_wait(0.0, speed_mps=0.150, force_n=40.0, timeout_s=3.0)
    elapsed = time.monotonic() - start
    assert final.object_status == ObjectStatus.CONTACT_CLOSING and final.requested == 255
    assert gripper.width_m(final) == pytest.approx(0.040, abs=0.085 / 255)
    assert elapsed >= 0.045 / 0.150 * 0.95  # the fingers took their time to get there
    assert emulator.command.force == gripper.scale.force_to_counts(40.0)
    # Opening to 60 mm: no object in the way.
    final = gripper.move_and_wait(0.060, speed_mps=0.150, force_n=40.0, timeout_s=3.0)
    assert final.object_status == ObjectStatus.AT_POSITION
    assert gripper.width_m(final) == pytest.approx(0.060, abs=0.085 / 255)


def test_a_command_lost_on_the_line_is_sent_again(server, gripper, emulator):
    # The close is lost, and a spare write echo from an earlier retried request (same
    # address and count, so nothing tells it apart) arrives as its acknowledgement:
    # only gPR, which never echoes the request, shows the gripper did not take it.
    gripper.activate(timeout_s=3.0)
    server.lose_requests = 1
    server.late_answers.append(bytes.fromhex("09 10 03 E8 00 03 01 30"))
    start = time.monotonic()
    final = gripper.move_and_wait(0.0, speed_mps=0.150, force_n=40.0, timeout_s=3.0)
    assert final.requested == 255 and final.object_status == ObjectStatus.CONTACT_CLOSING
    assert time.monotonic() - start < 0.5 + 0.045 / 0.150 + 1.0
    # Never taken (a device that acknowledges and ignores): the timeout says so.
    emulator.write_registers = lambda address, values: None
    with pytest.raises(GripperTimeout, match=r"requested 255.*sent \d+ times and never taken"):
        gripper.move_and_wait(0.060, speed_mps=0.150, force_n=40.0, timeout_s=1.5)


def test_motion_before_activation_is_refused(gripper):
    gripper.reset()
    with pytest.raises(GripperNotReady, match="activate it first"):
        gripper.move(0.0, 0.1, 40.0)
    with pytest.raises(ValueError, match="outside the gripper's range"):
        gripper.move(0.2, 0.1, 40.0)


def test_a_fault_during_motion_is_raised_with_its_meaning(gripper, emulator):
    gripper.activate(timeout_s=3.0)
    requested = gripper.move(0.0, speed_mps=0.020, force_n=40.0)
    emulator.inject_fault(0x0E)
    with pytest.raises(GripperFault, match="0x0E.*overcurrent"):
        gripper.wait(timeout_s=2.0, requested=requested)
    gripper.activate(timeout_s=3.0, force=True)  # reset + activate clears it
    assert gripper.read_state().fault == 0


def test_pymodbus_reads_and_writes_the_emulator(server, emulator):
    from pymodbus import FramerType
    from pymodbus.client import ModbusSerialClient

    client = ModbusSerialClient(server.port, framer=FramerType.RTU, baudrate=115200, timeout=1, retries=1)
    assert client.connect()
    try:
        close = [0x0900, 0x00FF, 0xFF00]
        assert not client.write_registers(COMMAND_ADDRESS, [0, 0, 0], device_id=9).isError()
        assert not client.write_registers(COMMAND_ADDRESS, [0x0100, 0, 0], device_id=9).isError()
        time.sleep(0.25)  # activation time of this emulator
        assert not client.write_registers(COMMAND_ADDRESS, close, device_id=9).isError()
        assert emulator.command.go and emulator.command.position == 255
        reply = client.read_input_registers(STATUS_ADDRESS, count=3, device_id=9)
        assert not reply.isError()
        state = GripperState.from_registers(reply.registers)
        assert state.ready and state.go and state.requested == 255
        both = client.readwrite_registers(
            read_address=STATUS_ADDRESS, read_count=3, write_address=COMMAND_ADDRESS, values=[0x0900, 0x0000, 0xFF00],
            device_id=9,
        )
        assert GripperState.from_registers(both.registers).requested == 0
        bad = client.read_holding_registers(0x0100, count=2, device_id=9)
        assert bad.isError() and bad.exception_code == ILLEGAL_DATA_ADDRESS
    finally:
        client.close()


def test_status_over_function_4_too(server, emulator):
    with Robotiq2F85(server.port, timeout_s=0.2, status_function=0x04) as g:
        assert g.activate(timeout_s=3.0).ready


def test_corrupted_answers_are_retried_and_silence_is_an_error_within_the_timeout(server, gripper):
    server.corrupt_responses = 1
    gripper.read_state()  # the corrupted answer is retried
    assert gripper.modbus.failed_attempts == 1 and server.corrupt_responses == 0
    server.respond = False
    start = time.monotonic()
    with pytest.raises(GripperLinkError, match=r"slave 9 .*3 attempts") as error:
        gripper.read_state()
    assert isinstance(error.value.__cause__, ModbusTimeout)  # the driver's own type, the line's cause
    assert time.monotonic() - start < 3 * 2 * 0.2 + 0.5  # attempts x (2 x timeout), never a hang
    server.respond = True
    gripper.read_state()


def _wait_for(predicate, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.005)
    return predicate()


def test_line_noise_costs_at_most_a_retry(server, gripper):
    with serial.Serial(server.tty_name, 115200, timeout=0.2) as noise:  # a second writer on the line
        noise.write(b"\x09\x03\x07")  # a truncated frame
        noise.write(bytes.fromhex("09 10 03 E8 00 03 06 01 00 00 00 00 00 00 00"))  # rACT=1, bad CRC
    for _ in range(3):
        assert gripper.read_state() is not None
    assert gripper.modbus.failed_attempts <= 1
    assert not gripper.read_state().activated  # the bad-CRC write was not executed


def test_broadcast_write_is_executed_without_an_answer(server, emulator, gripper):
    gripper.modbus.write_registers(0, COMMAND_ADDRESS, [0x0100, 0, 0])
    assert _wait_for(lambda: emulator.command.activate)
    assert gripper.read_state() is not None  # no stray answer confuses the next call


def test_port_vanishing_mid_move_then_returning(server, gripper, emulator):
    gripper.activate(timeout_s=3.0)
    requested = gripper.move(0.0, speed_mps=0.050, force_n=40.0)  # 0.8 s to the object
    server.unplug()
    start = time.monotonic()
    with pytest.raises(GripperLinkError, match="could not be reopened") as error:
        gripper.wait(timeout_s=3.0, requested=requested)
    assert isinstance(error.value.__cause__, ModbusConnectionError)
    assert time.monotonic() - start < 1.0
    assert emulator.state.moving  # the gripper carries on without its master
    server.replug()
    final = gripper.wait(timeout_s=3.0, requested=requested)  # same driver, port reopened
    assert final.object_status == ObjectStatus.CONTACT_CLOSING
    server.unplug()
    server.replug()  # replugged between two calls: the next call does not even fail
    assert gripper.read_state().object_detected


def test_only_the_drivers_own_errors_escape(server, gripper, monkeypatch):
    # pymodbus re-raises pyserial's BlockingIOError / InterruptedError as they are; the
    # driver reports them as the line's failure, as any other port error.
    def interrupted(*_):
        raise InterruptedError(4, "Interrupted system call")

    monkeypatch.setattr(gripper.modbus.client, "recv", interrupted)
    with pytest.raises(GripperLinkError, match="could not be reopened") as error:
        gripper.read_state()
    assert isinstance(error.value.__cause__, ModbusConnectionError)
    monkeypatch.undo()
    assert gripper.read_state() is not None  # the port was reopened by path
    # Closing a port that already failed reports EIO again: close() still never raises.
    monkeypatch.setattr(gripper.modbus.client.socket, "close", lambda: interrupted())
    gripper.close()
    assert not gripper.modbus.connected


def test_port_errors_say_what_to_check(server, gripper, tmp_path):
    with pytest.raises(GripperConnectionError, match="cannot open serial port .*dialout"):
        Robotiq2F85(str(tmp_path / "no-such-tty"))
    with pytest.raises(GripperConnectionError, match="no other program holds it"):
        Robotiq2F85(server.port)  # the fixture's driver holds it exclusively
    assert os.path.realpath(server.port) == server.tty_name


def test_symlink_is_removed_on_stop(emulator, tmp_path):
    link = tmp_path / "ttyX"
    srv = PtyModbusServer(emulator, link_path=str(link)).start()
    assert link.is_symlink()
    with Robotiq2F85(str(link)) as g:
        assert g.read_state() is not None
    srv.stop()
    assert not link.exists() and not link.is_symlink()


def test_benchmark_runs_and_ends_with_its_figure():
    import subprocess

    from ros_testing import executable

    out = subprocess.run(
        [str(executable("robotiq_driver", "bench_gripper")), "--n", "20"],
        capture_output=True, text=True, timeout=60, check=True,
    ).stdout.strip().splitlines()
    name, value = out[-1].split("=")
    assert name == "status_reads_per_s" and float(value) > 0
    figures = dict(line.split("=") for line in out)
    assert float(figures["close_on_40mm_object_s"]) >= 0.95 * float(figures["close_on_40mm_object_fingers_only_s"])
