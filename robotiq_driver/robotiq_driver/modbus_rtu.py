"""Modbus RTU framing and a serial client for the register functions a Robotiq gripper uses.

A frame is ``slave address | function | data | CRC-16 (little-endian)``. Only the four
register functions the 2F-85 speaks are implemented: 0x03 read holding registers,
0x04 read input registers, 0x10 write multiple registers and 0x17 read/write multiple
registers. Both sides live here: the client encodes requests and decodes responses, a
server (see ``pty_modbus_server``) decodes requests and encodes responses.

Frames are delimited by their length, which the function code fixes, rather than by
the 3.5-character silence of the standard: on a pseudo-terminal or a USB-RS485
adapter the silence is not observable, while the length always is.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass

READ_HOLDING_REGISTERS = 0x03
READ_INPUT_REGISTERS = 0x04
WRITE_MULTIPLE_REGISTERS = 0x10
READ_WRITE_MULTIPLE_REGISTERS = 0x17
SUPPORTED_FUNCTIONS = (
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    READ_WRITE_MULTIPLE_REGISTERS,
)

BROADCAST_ADDRESS = 0
MAX_READ_COUNT = 125  # Modbus application protocol v1.1b3, 6.3
MAX_WRITE_COUNT = 123  # 6.12; 121 for function 0x17, checked there

ILLEGAL_FUNCTION = 0x01
ILLEGAL_DATA_ADDRESS = 0x02
ILLEGAL_DATA_VALUE = 0x03
SERVER_DEVICE_FAILURE = 0x04
EXCEPTION_TEXT = {
    ILLEGAL_FUNCTION: "illegal function (the device does not implement this function code)",
    ILLEGAL_DATA_ADDRESS: "illegal data address (register range not mapped on the device)",
    ILLEGAL_DATA_VALUE: "illegal data value (malformed request or value out of range)",
    SERVER_DEVICE_FAILURE: "server device failure",
    0x05: "acknowledge (request accepted, processing takes long)",
    0x06: "server device busy",
}


class ModbusError(Exception):
    """Base class of every Modbus failure the client reports."""


class ModbusTimeout(ModbusError):
    """No (complete) response arrived in time."""


class ModbusCrcError(ModbusError):
    """A frame arrived whose CRC does not match its contents."""


class ModbusFrameError(ModbusError):
    """A frame arrived with a valid CRC but contents that do not fit the request."""


class ModbusExceptionResponse(ModbusError):
    """The device answered with a Modbus exception code."""

    def __init__(self, slave: int, function: int, code: int):
        self.slave, self.function, self.code = slave, function, code
        text = EXCEPTION_TEXT.get(code, "unknown exception code")
        super().__init__(
            f"slave {slave} rejected function 0x{function:02X} with exception "
            f"0x{code:02X}: {text}"
        )


class DeviceException(Exception):
    """Raised by a served device to make the server answer with a Modbus exception."""

    def __init__(self, code: int, reason: str = ""):
        self.code = code
        super().__init__(reason or EXCEPTION_TEXT.get(code, f"exception 0x{code:02X}"))


def crc16(data: bytes) -> int:
    """CRC-16/MODBUS (poly 0xA001 reflected, init 0xFFFF) of ``data``."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def with_crc(body: bytes) -> bytes:
    """Append the CRC, low byte first as RTU sends it."""
    return body + struct.pack("<H", crc16(body))


def crc_ok(frame: bytes) -> bool:
    return len(frame) >= 4 and crc16(frame[:-2]) == struct.unpack("<H", frame[-2:])[0]


def _check_slave(slave: int) -> None:
    if not 0 <= slave <= 247:
        raise ValueError(f"slave address {slave} out of range: use 1..247 (0 = broadcast)")


def _check_registers(values) -> tuple[int, ...]:
    values = tuple(int(v) for v in values)
    for v in values:
        if not 0 <= v <= 0xFFFF:
            raise ValueError(f"register value {v} does not fit 16 bits (0..65535)")
    return values


def _check_range(address: int, count: int, limit: int) -> None:
    if not 0 <= address <= 0xFFFF:
        raise ValueError(f"register address {address} out of range 0..65535")
    if not 1 <= count <= limit:
        raise ValueError(f"register count {count} out of range 1..{limit}")
    if address + count > 0x10000:
        raise ValueError(f"registers {address}..{address + count - 1} run past 65535")


# -- requests (client side) ---------------------------------------------------------


def read_registers_request(slave: int, function: int, address: int, count: int) -> bytes:
    """Frame for function 0x03 or 0x04."""
    _check_slave(slave)
    if function not in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        raise ValueError(f"function 0x{function:02X} is not a register read (use 0x03 or 0x04)")
    _check_range(address, count, MAX_READ_COUNT)
    return with_crc(struct.pack(">BBHH", slave, function, address, count))


def write_registers_request(slave: int, address: int, values) -> bytes:
    """Frame for function 0x10."""
    _check_slave(slave)
    values = _check_registers(values)
    _check_range(address, len(values), MAX_WRITE_COUNT)
    body = struct.pack(">BBHHB", slave, WRITE_MULTIPLE_REGISTERS, address, len(values), 2 * len(values))
    return with_crc(body + struct.pack(f">{len(values)}H", *values))


def read_write_registers_request(
    slave: int, read_address: int, read_count: int, write_address: int, values
) -> bytes:
    """Frame for function 0x17 (the device writes first, then reads)."""
    _check_slave(slave)
    values = _check_registers(values)
    _check_range(read_address, read_count, MAX_READ_COUNT)
    _check_range(write_address, len(values), 121)
    body = struct.pack(
        ">BBHHHHB",
        slave,
        READ_WRITE_MULTIPLE_REGISTERS,
        read_address,
        read_count,
        write_address,
        len(values),
        2 * len(values),
    )
    return with_crc(body + struct.pack(f">{len(values)}H", *values))


# -- requests (server side) ---------------------------------------------------------


@dataclass(frozen=True)
class Request:
    """A decoded request. Reads have ``read_*`` set, writes ``write_*``, 0x17 both."""

    slave: int
    function: int
    read_address: int = 0
    read_count: int = 0
    write_address: int = 0
    values: tuple[int, ...] = ()


class UnknownFunction(ModbusFrameError):
    """The request's function code is not one this module can size or decode."""


def request_length(buffer: bytes) -> int | None:
    """Length of the request frame at the start of ``buffer``; None until enough bytes.

    Raises UnknownFunction for a function code whose frame length is unknown.
    """
    if len(buffer) < 2:
        return None
    function = buffer[1]
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        return 8
    if function == WRITE_MULTIPLE_REGISTERS:
        return None if len(buffer) < 7 else 9 + buffer[6]
    if function == READ_WRITE_MULTIPLE_REGISTERS:
        return None if len(buffer) < 11 else 13 + buffer[10]
    raise UnknownFunction(f"function 0x{function:02X} not supported")


def decode_request(frame: bytes) -> Request:
    """Decode one complete request frame (CRC included).

    Raises ModbusCrcError for a corrupted frame (a device stays silent on those) and
    DeviceException(ILLEGAL_DATA_VALUE) for a well-formed frame with bad counts.
    """
    if not crc_ok(frame):
        raise ModbusCrcError(f"request CRC mismatch in {frame.hex(' ')}")
    slave, function = frame[0], frame[1]
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        address, count = struct.unpack(">HH", frame[2:6])
        if not 1 <= count <= MAX_READ_COUNT:
            raise DeviceException(ILLEGAL_DATA_VALUE, f"read count {count} not in 1..125")
        return Request(slave, function, read_address=address, read_count=count)
    if function == WRITE_MULTIPLE_REGISTERS:
        address, count, nbytes = struct.unpack(">HHB", frame[2:7])
        if not 1 <= count <= MAX_WRITE_COUNT or nbytes != 2 * count:
            raise DeviceException(ILLEGAL_DATA_VALUE, f"write count {count} / byte count {nbytes}")
        values = struct.unpack(f">{count}H", frame[7 : 7 + nbytes])
        return Request(slave, function, write_address=address, values=values)
    if function == READ_WRITE_MULTIPLE_REGISTERS:
        raddr, rcount, waddr, wcount, nbytes = struct.unpack(">HHHHB", frame[2:11])
        if not 1 <= rcount <= MAX_READ_COUNT or not 1 <= wcount <= 121 or nbytes != 2 * wcount:
            raise DeviceException(ILLEGAL_DATA_VALUE, "read/write counts out of range")
        values = struct.unpack(f">{wcount}H", frame[11 : 11 + nbytes])
        return Request(slave, function, raddr, rcount, waddr, values)
    raise DeviceException(ILLEGAL_FUNCTION)


def encode_response(request: Request, registers_read=()) -> bytes:
    """Normal response to ``request``; ``registers_read`` for the read functions."""
    if request.function == WRITE_MULTIPLE_REGISTERS:
        return with_crc(
            struct.pack(">BBHH", request.slave, request.function, request.write_address, len(request.values))
        )
    values = _check_registers(registers_read)
    if len(values) != request.read_count:
        raise ValueError(f"{len(values)} registers read, request asked for {request.read_count}")
    body = struct.pack(">BBB", request.slave, request.function, 2 * len(values))
    return with_crc(body + struct.pack(f">{len(values)}H", *values))


def encode_exception(slave: int, function: int, code: int) -> bytes:
    return with_crc(struct.pack(">BBB", slave, function | 0x80, code))


# -- responses (client side) --------------------------------------------------------


def response_length(buffer: bytes) -> int | None:
    """Length of the response frame at the start of ``buffer``; None until enough bytes."""
    if len(buffer) < 3:
        return None
    function = buffer[1]
    if function & 0x80:
        return 5
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS, READ_WRITE_MULTIPLE_REGISTERS):
        return 5 + buffer[2]
    if function == WRITE_MULTIPLE_REGISTERS:
        return 8
    raise ModbusFrameError(f"response with unexpected function 0x{function:02X}: {buffer.hex(' ')}")


def decode_response(frame: bytes, request: bytes) -> tuple[int, ...]:
    """Check ``frame`` answers ``request`` and return the registers it carries.

    A write's response carries no registers and returns ().
    """
    if not crc_ok(frame):
        raise ModbusCrcError(f"response CRC mismatch in {frame.hex(' ')}")
    slave, function = request[0], request[1]
    if frame[0] != slave:
        raise ModbusFrameError(f"response from slave {frame[0]}, expected slave {slave}")
    if frame[1] == function | 0x80:
        raise ModbusExceptionResponse(slave, function, frame[2])
    if frame[1] != function:
        raise ModbusFrameError(f"response function 0x{frame[1]:02X}, expected 0x{function:02X}")
    if function == WRITE_MULTIPLE_REGISTERS:
        if frame[2:6] != request[2:6]:
            raise ModbusFrameError(
                f"write echo {frame[2:6].hex(' ')} does not match request {request[2:6].hex(' ')}"
            )
        return ()
    count = struct.unpack(">H", request[4:6])[0]
    if frame[2] != 2 * count:
        raise ModbusFrameError(f"response carries {frame[2]} bytes, expected {2 * count}")
    return struct.unpack(f">{count}H", frame[3 : 3 + 2 * count])


# -- client -------------------------------------------------------------------------


class ModbusRtuClient:
    """Request/response transactions over a pyserial-like port.

    ``port`` needs ``write``, ``read(n)`` (returning early on its own timeout, which
    this sets), and ``reset_input_buffer``. Timeouts and CRC errors are
    retried ``retries`` times; exception responses are not (asking again would give
    the same answer).
    """

    def __init__(self, port, timeout_s: float = 0.1, retries: int = 2, name: str = "serial port"):
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.port, self.timeout_s, self.retries, self.name = port, timeout_s, retries, name
        # Reads return at least this often, so the loop below keeps its deadline. Set
        # once: pyserial reconfigures the tty (tcsetattr) on every timeout change.
        self.port.timeout = min(timeout_s, 0.02)
        self.transactions = 0
        self.failed_attempts = 0

    def transact(self, request: bytes) -> tuple[int, ...]:
        last_error: ModbusError | None = None
        for _ in range(self.retries + 1):
            try:
                result = self._attempt(request)
                self.transactions += 1
                return result
            except (ModbusTimeout, ModbusCrcError) as error:
                self.failed_attempts += 1
                last_error = error
        attempts = self.retries + 1
        if isinstance(last_error, ModbusTimeout):
            raise ModbusTimeout(
                f"no answer from slave {request[0]} on {self.name} within {self.timeout_s} s "
                f"({attempts} attempts): check power, cabling, baud rate and slave id"
            )
        raise ModbusCrcError(f"{last_error} ({attempts} attempts): check cabling and termination")

    def _attempt(self, request: bytes) -> tuple[int, ...]:
        self.port.reset_input_buffer()  # a late answer to an earlier attempt is stale
        self.port.write(request)
        if request[0] == BROADCAST_ADDRESS:
            return ()
        deadline = time.monotonic() + self.timeout_s
        buffer = b""
        needed = 3
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                detail = f" (got {buffer.hex(' ')})" if buffer else ""
                raise ModbusTimeout(f"timed out after {self.timeout_s} s{detail}")
            buffer += self.port.read(needed - len(buffer))
            if len(buffer) < needed:
                continue
            length = response_length(buffer)
            if length is not None and len(buffer) >= length:
                return decode_response(buffer[:length], request)
            needed = length if length is not None else len(buffer) + 1

    def read_holding_registers(self, slave: int, address: int, count: int) -> tuple[int, ...]:
        return self.transact(read_registers_request(slave, READ_HOLDING_REGISTERS, address, count))

    def read_input_registers(self, slave: int, address: int, count: int) -> tuple[int, ...]:
        return self.transact(read_registers_request(slave, READ_INPUT_REGISTERS, address, count))

    def write_registers(self, slave: int, address: int, values) -> None:
        self.transact(write_registers_request(slave, address, values))

    def read_write_registers(
        self, slave: int, read_address: int, read_count: int, write_address: int, values
    ) -> tuple[int, ...]:
        return self.transact(
            read_write_registers_request(slave, read_address, read_count, write_address, values)
        )
