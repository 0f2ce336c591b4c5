"""Modbus RTU framing, checked byte for byte against the frames printed in the Robotiq
2F-85 manual's Modbus RTU example (slave 9)."""
import pytest

from robotiq_driver import modbus_rtu as rtu

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


def test_requests_match_the_manual_byte_for_byte():
    assert rtu.write_registers_request(9, 0x03E8, [0, 0, 0]) == b(MANUAL_CLEAR_RACT)
    assert rtu.write_registers_request(9, 0x03E8, [0x0900, 0x00FF, 0xFFFF]) == b(MANUAL_CLOSE)
    assert rtu.write_registers_request(9, 0x03E8, [0x0900, 0x0000, 0xFFFF]) == b(MANUAL_OPEN)
    assert rtu.read_registers_request(9, rtu.READ_HOLDING_REGISTERS, 0x07D0, 1) == b(MANUAL_READ_STATUS_1)
    assert rtu.read_registers_request(9, rtu.READ_HOLDING_REGISTERS, 0x07D0, 3) == b(MANUAL_READ_STATUS_3)


def test_responses_from_the_manual_decode_to_their_registers():
    assert rtu.decode_response(b(MANUAL_STATUS_ACTIVATING), b(MANUAL_READ_STATUS_1)) == (0x1100,)
    assert rtu.decode_response(b(MANUAL_STATUS_ACTIVATED), b(MANUAL_READ_STATUS_1)) == (0x3100,)
    assert rtu.decode_response(b(MANUAL_STATUS_CLOSING), b(MANUAL_READ_STATUS_3)) == (0x3900, 0x00FF, 0x0E0A)
    assert rtu.decode_response(b(MANUAL_STATUS_CONTACT), b(MANUAL_READ_STATUS_3)) == (0xB900, 0x00FF, 0xBD00)
    assert rtu.decode_response(b(MANUAL_WRITE_ACK), b(MANUAL_CLOSE)) == ()


def test_server_side_decodes_and_answers_like_the_manual():
    request = rtu.decode_request(b(MANUAL_CLOSE))
    assert request == rtu.Request(9, 0x10, write_address=0x03E8, values=(0x0900, 0x00FF, 0xFFFF))
    assert rtu.encode_response(request) == b(MANUAL_WRITE_ACK)
    read = rtu.decode_request(b(MANUAL_READ_STATUS_3))
    assert rtu.encode_response(read, [0xB900, 0x00FF, 0xBD00]) == b(MANUAL_STATUS_CONTACT)


def test_frame_lengths_are_known_from_the_header():
    close = b(MANUAL_CLOSE)
    assert [rtu.request_length(close[:n]) for n in (1, 6, 7)] == [None, None, len(close)]
    assert rtu.request_length(b(MANUAL_READ_STATUS_1)[:2]) == 8
    assert rtu.response_length(b(MANUAL_STATUS_CONTACT)[:3]) == 11
    assert rtu.response_length(b(MANUAL_WRITE_ACK)[:3]) == 8
    assert rtu.response_length(rtu.encode_exception(9, 3, 2)[:3]) == 5
    with pytest.raises(rtu.UnknownFunction):
        rtu.request_length(b"\x09\x2b")


def test_read_write_multiple_round_trip():
    frame = rtu.read_write_registers_request(9, 0x07D0, 3, 0x03E8, [0x0900, 0x0080, 0xFF10])
    request = rtu.decode_request(frame)
    assert request.read_address == 0x07D0 and request.read_count == 3
    assert request.write_address == 0x03E8 and request.values == (0x0900, 0x0080, 0xFF10)
    assert rtu.request_length(frame) == len(frame)
    response = rtu.encode_response(request, [1, 2, 3])
    assert rtu.decode_response(response, frame) == (1, 2, 3)


def test_corruption_and_mismatches_are_reported():
    bad = bytearray(b(MANUAL_STATUS_CONTACT))
    bad[5] ^= 0x01
    with pytest.raises(rtu.ModbusCrcError):
        rtu.decode_response(bytes(bad), b(MANUAL_READ_STATUS_3))
    with pytest.raises(rtu.ModbusCrcError):
        rtu.decode_request(b(MANUAL_CLOSE)[:-1] + b"\x00")
    other_slave = rtu.with_crc(b"\x0a" + b(MANUAL_STATUS_CONTACT)[1:-2])
    with pytest.raises(rtu.ModbusFrameError, match="slave 10"):
        rtu.decode_response(other_slave, b(MANUAL_READ_STATUS_3))
    # A 1-register answer to a 3-register read must not be accepted.
    with pytest.raises(rtu.ModbusFrameError, match="expected 6"):
        rtu.decode_response(b(MANUAL_STATUS_ACTIVATED), b(MANUAL_READ_STATUS_3))
    with pytest.raises(rtu.ModbusExceptionResponse, match="illegal data address"):
        rtu.decode_response(rtu.encode_exception(9, 3, rtu.ILLEGAL_DATA_ADDRESS), b(MANUAL_READ_STATUS_3))


def test_invalid_arguments_fail_with_a_reason():
    with pytest.raises(ValueError, match="slave address 300"):
        rtu.read_registers_request(300, 3, 0, 1)
    with pytest.raises(ValueError, match="count 126"):
        rtu.read_registers_request(9, 3, 0, 126)
    with pytest.raises(ValueError, match="16 bits"):
        rtu.write_registers_request(9, 0, [70000])
    with pytest.raises(ValueError, match="not a register read"):
        rtu.read_registers_request(9, 0x10, 0, 1)
    with pytest.raises(rtu.DeviceException):
        rtu.decode_request(rtu.with_crc(bytes([9, 3, 0, 0, 0, 0])))  # zero-register read


class ScriptedPort:
    """A serial port whose answers are scripted: each write pops the next reply."""

    def __init__(self, replies):
        self.replies, self.written, self.pending, self.timeout = list(replies), [], b"", None

    def reset_input_buffer(self):
        self.pending = b""

    def write(self, data):
        self.written.append(bytes(data))
        self.pending = self.replies.pop(0) if self.replies else b""

    def read(self, n):
        out, self.pending = self.pending[:n], self.pending[n:]
        return out


def test_client_retries_a_corrupted_answer_then_succeeds():
    corrupted = b(MANUAL_STATUS_CONTACT)[:-1] + b"\x00"
    port = ScriptedPort([corrupted, b(MANUAL_STATUS_CONTACT)])
    client = rtu.ModbusRtuClient(port, timeout_s=0.05, retries=1)
    assert client.read_holding_registers(9, 0x07D0, 3) == (0xB900, 0x00FF, 0xBD00)
    assert port.written == [b(MANUAL_READ_STATUS_3)] * 2
    assert client.failed_attempts == 1


def test_client_gives_up_after_its_retries_with_a_clear_message():
    port = ScriptedPort([b"", b"", b""])
    client = rtu.ModbusRtuClient(port, timeout_s=0.02, retries=2, name="/dev/ttyTEST")
    with pytest.raises(rtu.ModbusTimeout, match=r"slave 9 on /dev/ttyTEST .*3 attempts"):
        client.read_holding_registers(9, 0x07D0, 3)
    assert len(port.written) == 3


def test_client_does_not_retry_an_exception_response():
    port = ScriptedPort([rtu.encode_exception(9, 3, rtu.ILLEGAL_DATA_ADDRESS)] * 3)
    client = rtu.ModbusRtuClient(port, timeout_s=0.05, retries=2)
    with pytest.raises(rtu.ModbusExceptionResponse):
        client.read_holding_registers(9, 0x0000, 3)
    assert len(port.written) == 1
