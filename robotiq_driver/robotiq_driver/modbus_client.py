"""The Modbus RTU client the driver talks through: pymodbus's serial client (RTU framer,
pyserial underneath), with the driver's error contract on top.

pymodbus does the framing, the CRC and the retries; this adds what a gripper driver
needs from it:

- every call is bounded: an attempt waits at most ~2 x ``timeout_s`` for its answer
  (pymodbus waits up to ``timeout_s`` for the first byte, then again for the rest), and
  a call makes at most ``retries + 1`` attempts;
- a silent device and an answer with a bad CRC look alike on the line (pymodbus drops
  a corrupted frame and keeps waiting), and both are retried; after the last attempt
  ``ModbusTimeout`` says what to check;
- an exception response is not retried (asking again gives the same answer):
  ``ModbusExceptionResponse`` carries the code and its meaning;
- an answer must be the answer to this request: its function code, and for a write
  the echoed address and count, for a read the register count. pymodbus does not
  match answers to requests on a serial line, so a late answer to an earlier request
  (the device was slow, the client retried, the spare answer arrived after the next
  request went out) would otherwise pass for this one: a read would return the wrong
  registers, a write would look applied although the device never saw it. Such an
  answer is discarded and the request sent again (reads and register writes can be
  repeated), within the same attempts;
- a port that fails on write or read (unplugged USB adapter: EIO) is closed and
  reopened by path within the same call's attempts, so a replugged adapter that comes
  back under the same path (/dev/serial/by-id/...) is picked up without a restart; if
  it is not back, ``ModbusConnectionError``, and the next call tries again.
"""

from __future__ import annotations

import logging

import serial
from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

# pymodbus logs every lost answer at ERROR (with a frame dump); the driver raises
# instead. Without a handler of their own those records would reach stderr through
# logging's last resort; an application that configures logging still gets them.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

READ_HOLDING_REGISTERS = 0x03
READ_INPUT_REGISTERS = 0x04
WRITE_MULTIPLE_REGISTERS = 0x10
MAX_READ_COUNT = 125  # Modbus application protocol v1.1b3, 6.3
MAX_WRITE_COUNT = 123  # 6.12

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
    """No valid answer (none, or only corrupted ones) after all attempts."""


class ModbusConnectionError(ModbusError):
    """The serial port cannot be opened, or failed and could not be reopened."""


class ModbusFrameError(ModbusError):
    """A valid frame arrived whose contents do not fit the request."""


class ModbusExceptionResponse(ModbusError):
    """The device answered with a Modbus exception code."""

    def __init__(self, slave: int, function: int, code: int):
        self.slave, self.function, self.code = slave, function, code
        text = EXCEPTION_TEXT.get(code, "unknown exception code")
        super().__init__(
            f"slave {slave} rejected function 0x{function:02X} with exception 0x{code:02X}: {text}"
        )


def _check_slave(slave: int) -> None:
    if not 0 <= slave <= 247:
        raise ValueError(f"slave address {slave} out of range: use 1..247 (0 = broadcast)")


def _check_range(address: int, count: int, limit: int) -> None:
    if not 0 <= address <= 0xFFFF:
        raise ValueError(f"register address {address} out of range 0..65535")
    if not 1 <= count <= limit:
        raise ValueError(f"register count {count} out of range 1..{limit}")
    if address + count > 0x10000:
        raise ValueError(f"registers {address}..{address + count - 1} run past 65535")


class ModbusRtuClient:
    """Register transactions with one serial line's devices, through pymodbus.

    Not thread-safe on its own (the driver holds a lock around each call).
    ``transactions`` counts successful calls, ``failed_attempts`` attempts that got no
    valid answer (each was retried or ended the call).
    """

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        timeout_s: float = 0.1,
        retries: int = 2,
        bytesize: int = 8,
        parity: str = "N",
        stopbits: int = 1,
    ):
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.port, self.timeout_s, self.retries = port, timeout_s, retries
        self._serial_settings = dict(
            baudrate=baudrate, bytesize=bytesize, parity=parity, stopbits=stopbits
        )
        self.client = ModbusSerialClient(
            port,
            framer=FramerType.RTU,
            timeout=timeout_s,
            retries=retries,
            name=port,
            **self._serial_settings,
        )
        self.transactions = 0
        self.failed_attempts = 0

    # -- port ---------------------------------------------------------------------

    def connect(self) -> None:
        """Open the port (exclusively); ModbusConnectionError says why it would not."""
        if self.client.connect():
            return
        raise ModbusConnectionError(f"cannot open serial port {self.port!r}: {self._open_error()}")

    def _open_error(self) -> str:
        """pymodbus only logs why the port did not open; ask pyserial the same question."""
        try:
            probe = serial.Serial(self.port, exclusive=True, timeout=0, **self._serial_settings)
        except (serial.SerialException, OSError, ValueError) as error:
            return str(error)
        probe.close()
        return "the port opened on a second try; retry"

    def close(self) -> None:
        """Release the port. Never raises: closing the fd of a failed port can report
        the failure again (EIO), and the handle is dropped either way, so the next
        ``connect`` or call reopens the port by path."""
        try:
            self.client.close()
        except OSError:
            self.client.socket = None

    @property
    def connected(self) -> bool:
        return self.client.connected

    # -- transactions ---------------------------------------------------------------

    def read_holding_registers(self, slave: int, address: int, count: int) -> tuple[int, ...]:
        _check_slave(slave)
        _check_range(address, count, MAX_READ_COUNT)
        response = self._execute(
            slave, READ_HOLDING_REGISTERS,
            lambda: self.client.read_holding_registers(address, count=count, device_id=slave),
            lambda r: len(r.registers) == count,
        )
        return tuple(response.registers)

    def read_input_registers(self, slave: int, address: int, count: int) -> tuple[int, ...]:
        _check_slave(slave)
        _check_range(address, count, MAX_READ_COUNT)
        response = self._execute(
            slave, READ_INPUT_REGISTERS,
            lambda: self.client.read_input_registers(address, count=count, device_id=slave),
            lambda r: len(r.registers) == count,
        )
        return tuple(response.registers)

    def write_registers(self, slave: int, address: int, values) -> None:
        _check_slave(slave)
        values = [int(v) for v in values]
        _check_range(address, len(values), MAX_WRITE_COUNT)
        for v in values:
            if not 0 <= v <= 0xFFFF:
                raise ValueError(f"register value {v} does not fit 16 bits (0..65535)")
        broadcast = slave == 0  # executed by every device, answered by none
        self._execute(
            slave, WRITE_MULTIPLE_REGISTERS,
            lambda: self.client.write_registers(
                address, values, device_id=slave, no_response_expected=broadcast
            ),
            lambda r: (r.address, r.count) == (address, len(values)),
        )

    def _execute(self, slave: int, function: int, call, answers):
        """``answers(response)``: whether a response of ``function`` fits this request."""
        attempts = self.retries + 1
        port_error: Exception | None = None
        stale = None
        # Attempts cover port failures and answers to other requests; pymodbus retries
        # lost answers itself.
        for _ in range(attempts):
            try:
                response = call()
            except (ConnectionException, OSError) as error:
                # The port failed (EIO: adapter unplugged) or will not reopen. pymodbus
                # closed it; the next attempt reopens it by path. pymodbus turns pyserial's
                # errors into ConnectionException, except the ones it re-raises as they
                # are (BlockingIOError, InterruptedError): those are the line's too.
                self.close()
                self.failed_attempts += 1
                port_error = error
                continue
            except ModbusIOException:
                self.failed_attempts += attempts
                raise ModbusTimeout(
                    f"no answer from slave {slave} on {self.port} within {self.timeout_s} s "
                    f"({attempts} attempt{'s' if attempts > 1 else ''}; a corrupted answer counts as "
                    "none): check power, cabling, termination, baud rate and slave id"
                ) from None
            except ModbusException as error:
                raise ModbusError(f"Modbus failure with slave {slave} on {self.port}: {error}") from error
            if response is None:  # broadcast: nothing to wait for
                self.transactions += 1
                return None
            self.failed_attempts += getattr(response, "retries", 0)
            if (response.function_code & 0x7F) != function or not (response.isError() or answers(response)):
                # Another request's late answer; this request's own may still come, and
                # pymodbus drops what is waiting before it sends again.
                self.failed_attempts += 1
                stale = response
                continue
            if response.isError():
                raise ModbusExceptionResponse(slave, function, getattr(response, "exception_code", 0))
            self.transactions += 1
            return response
        if stale is not None and port_error is None:
            raise ModbusFrameError(
                f"slave {slave} on {self.port} kept giving answers that do not fit the request "
                f"(function 0x{function:02X}; last answer: function 0x{stale.function_code:02X}, "
                f"{self._describe(stale)}) in {attempts} attempt{'s' if attempts > 1 else ''}: "
                "is another master on the line, or a second program on the port?"
            )
        raise ModbusConnectionError(
            f"serial port {self.port} failed and could not be reopened "
            f"({attempts} attempt{'s' if attempts > 1 else ''}): "
            f"{self._open_error() if not self.client.connected else port_error}. Check the cable and "
            "the USB adapter; the next call tries to reopen it"
        )

    @staticmethod
    def _describe(response) -> str:
        if response.isError():
            return f"exception 0x{getattr(response, 'exception_code', 0):02X}"
        if response.function_code == WRITE_MULTIPLE_REGISTERS:
            return f"write echo of {response.count} registers at 0x{response.address:04X}"
        return f"{len(response.registers)} registers"
