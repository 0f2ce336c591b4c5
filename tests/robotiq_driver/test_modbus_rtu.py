"""Modbus RTU on the wire: pymodbus's RTU frames, checked byte for byte against the
frames printed in the Robotiq 2F-85 manual's Modbus RTU example (slave 9), and the
driver's client (pymodbus underneath) against the emulator's pymodbus server on a pty:
timeouts, retries, exception responses, a lost port."""
import time

import pytest
from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    ReadHoldingRegistersResponse,
    WriteMultipleRegistersRequest,
    WriteMultipleRegistersResponse,
)

from robotiq_driver import modbus_client as mb
from robotiq_driver.emulator.emulated_gripper import GripperEmulator, KinematicFingers
from robotiq_driver.emulator.pty_modbus_server import PtyModbusServer
from robotiq_driver.gripper_registers import COMMAND_ADDRESS, STATUS_ADDRESS

# Request/response pairs from the manual's example (activation, close, status reads).
MANUAL_CLEAR_RACT = "09 10 03 E8 00 03 06 00 00 00 00 00 00 73 30"
MANUAL_WRITE_ACK = "09 10 03 E8 00 03 01 30"
MANUAL_READ_STATUS_1 = "09 03 07 D0 00 01 85 CF"
MANUAL_STATUS_ACTIVATING = "09 03 02 11 00 55 D5"
MANUAL_STATUS_ACTIVATED = "09 03 02 31 00 4C 15"
MANUAL_CLOSE = "09 10 03 E8 00 03 06 09 00 00 FF FF FF 42 29"
MANUAL_OPEN = "09 10 03 E8 00 03 06 09 00 00 00 FF FF 72 19"
MANUAL_READ_STATUS_3 = "09 03 07 D0 00 03 04 0E"
MANUAL_STATUS_CLOSING = "09 03 06 39 00 00 FF 0E 0A F7 8B"
MANUAL_STATUS_CONTACT = "09 03 06 B9 00 00 FF BD 00 1D 7C"


def b(hex_text: str) -> bytes:
    return bytes.fromhex(hex_text)


def client_framer() -> FramerRTU:
    return FramerRTU(DecodePDU(False))


def test_pymodbus_requests_match_the_manual_byte_for_byte():
    framer = client_framer()

    def write(values):
        return framer.buildFrame(WriteMultipleRegistersRequest(address=0x03E8, registers=values, dev_id=9))

    def read(count):
        return framer.buildFrame(ReadHoldingRegistersRequest(address=0x07D0, count=count, dev_id=9))

    assert write([0, 0, 0]) == b(MANUAL_CLEAR_RACT)
    assert write([0x0900, 0x00FF, 0xFFFF]) == b(MANUAL_CLOSE)
    assert write([0x0900, 0x0000, 0xFFFF]) == b(MANUAL_OPEN)
    assert read(1) == b(MANUAL_READ_STATUS_1)
    assert read(3) == b(MANUAL_READ_STATUS_3)


def test_manual_responses_decode_with_pymodbus_and_its_server_frames_match():
    def decode(frame):
        used, pdu = client_framer().handleFrame(b(frame), 9, 0)
        assert used == len(b(frame)) and pdu is not None
        return pdu

    assert decode(MANUAL_STATUS_ACTIVATING).registers == [0x1100]
    assert decode(MANUAL_STATUS_ACTIVATED).registers == [0x3100]
    assert decode(MANUAL_STATUS_CLOSING).registers == [0x3900, 0x00FF, 0x0E0A]
    assert decode(MANUAL_STATUS_CONTACT).registers == [0xB900, 0x00FF, 0xBD00]
    assert isinstance(decode(MANUAL_WRITE_ACK), WriteMultipleRegistersResponse)
    framer = client_framer()
    contact = ReadHoldingRegistersResponse(registers=[0xB900, 0x00FF, 0xBD00], dev_id=9)
    assert framer.buildFrame(contact) == b(MANUAL_STATUS_CONTACT)
    assert framer.buildFrame(WriteMultipleRegistersResponse(address=0x03E8, count=3, dev_id=9)) == b(MANUAL_WRITE_ACK)


def test_a_corrupted_frame_is_not_accepted():
    bad = bytearray(b(MANUAL_STATUS_CONTACT))
    bad[5] ^= 0x01
    assert client_framer().handleFrame(bytes(bad), 9, 0)[1] is None


def test_invalid_arguments_fail_before_the_wire(server):
    client = mb.ModbusRtuClient(server.port)
    with pytest.raises(ValueError, match="slave address 300"):
        client.read_holding_registers(300, STATUS_ADDRESS, 1)
    with pytest.raises(ValueError, match="count 126"):
        client.read_holding_registers(9, 0, 126)
    with pytest.raises(ValueError, match="16 bits"):
        client.write_registers(9, COMMAND_ADDRESS, [70000])
    assert server.requests_served == 0


# -- the client against the emulator's pymodbus server ------------------------------


@pytest.fixture
def server(tmp_path):
    emulator = GripperEmulator(KinematicFingers(), activation_time_s=0.1)
    with PtyModbusServer(emulator, link_path=str(tmp_path / "ttyRobotiq")) as srv:
        yield srv


@pytest.fixture
def client(server):
    c = mb.ModbusRtuClient(server.port, timeout_s=0.2, retries=2)
    c.connect()
    yield c
    c.close()


def test_reads_both_functions_and_writes(client, server):
    client.write_registers(9, COMMAND_ADDRESS, [0x0100, 0, 0])
    assert client.read_holding_registers(9, COMMAND_ADDRESS, 3) == (0x0100, 0, 0)
    assert len(client.read_input_registers(9, STATUS_ADDRESS, 3)) == 3
    assert client.transactions == 3 and client.failed_attempts == 0


def test_a_corrupted_answer_is_retried(client, server):
    server.corrupt_responses = 1
    assert len(client.read_holding_registers(9, STATUS_ADDRESS, 3)) == 3
    assert client.failed_attempts == 1 and server.corrupt_responses == 0


def test_a_silent_device_gives_a_clear_error_within_the_timeout(client, server):
    server.respond = False
    start = time.monotonic()
    with pytest.raises(mb.ModbusTimeout, match=r"no answer from slave 9 on .*ttyRobotiq.*3 attempts"):
        client.read_holding_registers(9, STATUS_ADDRESS, 3)
    assert time.monotonic() - start < 3 * 2 * 0.2 + 0.5
    with pytest.raises(mb.ModbusTimeout, match="slave 10"):
        client.read_holding_registers(10, STATUS_ADDRESS, 3)  # another slave's address: silence
    server.respond = True
    assert client.read_holding_registers(9, STATUS_ADDRESS, 3)


def test_a_write_answered_by_a_late_read_answer_is_sent_again(client, server):
    # Under load the two cross: the write is lost on the line, and the spare answer to
    # an earlier, retried status read arrives in its place. Taken as the write's
    # answer it would make a command look applied that the device never saw.
    server.lose_requests = 1
    server.late_answers.append(b(MANUAL_STATUS_CONTACT))
    client.write_registers(9, COMMAND_ADDRESS, [0x0900, 0x00FF, 0xFFFF])
    assert server.device.command.to_registers() == (0x0900, 0x00FF, 0xFFFF)
    assert client.failed_attempts >= 1 and client.transactions == 1


def test_a_read_answered_by_a_late_write_echo_is_sent_again(client, server):
    client.write_registers(9, COMMAND_ADDRESS, [0x0100, 0, 0])
    server.late_answers.append(b(MANUAL_WRITE_ACK))
    assert client.read_holding_registers(9, COMMAND_ADDRESS, 3) == (0x0100, 0, 0)
    server.late_answers.append(b(MANUAL_STATUS_ACTIVATED))  # one register, not three
    assert client.read_holding_registers(9, COMMAND_ADDRESS, 3) == (0x0100, 0, 0)
    assert client.failed_attempts >= 2


def test_only_answers_to_other_requests_give_a_clear_error(client, server):
    server.lose_requests = 3
    server.late_answers.extend([b(MANUAL_STATUS_CONTACT)] * 3)
    with pytest.raises(mb.ModbusFrameError, match=r"do not fit the request \(function 0x10; last answer: "
                                                  r"function 0x03, 3 registers\) in 3 attempts"):
        client.write_registers(9, COMMAND_ADDRESS, [0x0900, 0x00FF, 0xFFFF])
    assert server.device.command.to_registers() != (0x0900, 0x00FF, 0xFFFF)
    client.write_registers(9, COMMAND_ADDRESS, [0x0900, 0x00FF, 0xFFFF])  # the line is fine again
    assert server.device.command.to_registers() == (0x0900, 0x00FF, 0xFFFF)


def test_an_exception_response_is_raised_not_retried(client, server):
    served = server.requests_served
    with pytest.raises(mb.ModbusExceptionResponse, match="exception 0x02: illegal data address") as error:
        client.read_holding_registers(9, 0x0100, 2)
    assert error.value.code == mb.ILLEGAL_DATA_ADDRESS and error.value.function == 0x03
    with pytest.raises(mb.ModbusExceptionResponse, match="function 0x10"):
        client.write_registers(9, STATUS_ADDRESS, [1])  # status registers are read-only
    assert server.requests_served == served + 2


def test_a_vanished_port_is_reported_then_reopened(client, server):
    assert client.read_holding_registers(9, STATUS_ADDRESS, 3)
    server.unplug()
    start = time.monotonic()
    with pytest.raises(mb.ModbusConnectionError, match="could not be reopened .*No such file"):
        client.read_holding_registers(9, STATUS_ADDRESS, 3)
    assert time.monotonic() - start < 1.0
    server.replug()
    assert client.read_holding_registers(9, STATUS_ADDRESS, 3)  # same path, new pty


def test_a_port_that_will_not_open_says_why(tmp_path, server):
    with pytest.raises(mb.ModbusConnectionError, match="cannot open serial port .*no-such-tty"):
        mb.ModbusRtuClient(str(tmp_path / "no-such-tty")).connect()
