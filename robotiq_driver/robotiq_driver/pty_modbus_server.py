"""A Modbus RTU server on a pseudo-terminal, serving one register device.

The server owns the pty's master side; a client opens the slave side (``port``, or the
symlink ``link_path``) like any serial port, e.g. with pyserial, and exchanges real RTU
frames with it. The device is anything with ``read_registers(address, count)`` and
``write_registers(address, values)`` that raises ``modbus_rtu.DeviceException`` for an
exception response; ``advance()`` is called between frames if the device has one.

As a Modbus device does, the server stays silent on frames with a bad CRC and on frames
for other slave addresses, and executes broadcast (address 0) writes without answering.
``respond = False`` and ``corrupt_responses`` emulate a gripper that stopped answering
and a noisy line, for testing clients.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty

from .modbus_rtu import (
    BROADCAST_ADDRESS,
    ILLEGAL_FUNCTION,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    READ_WRITE_MULTIPLE_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    DeviceException,
    UnknownFunction,
    crc_ok,
    decode_request,
    encode_exception,
    encode_response,
    request_length,
)


class PtyModbusServer:
    def __init__(
        self,
        device,
        slave_id: int = 9,
        link_path: str | None = None,
        frame_timeout_s: float = 0.02,
        tick_s: float = 0.005,
    ):
        if not 1 <= slave_id <= 247:
            raise ValueError(f"slave_id {slave_id} out of range 1..247")
        self.device = device
        self.slave_id = slave_id
        self.link_path = link_path
        # A partial frame older than this is dropped. The standard's 3.5 characters
        # (1.75 ms above 19200 baud) is too tight for a Python thread on a busy machine.
        self.frame_timeout_s = frame_timeout_s
        self.tick_s = tick_s
        self.respond = True
        self.corrupt_responses = 0
        self.requests_served = 0
        self.crc_errors = 0
        self.dropped_bytes = 0
        self._master = self._slave = None
        self._tty_name = ""
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    @property
    def port(self) -> str:
        """Path a client opens: the symlink if one was asked for, else the pty."""
        return self.link_path or self._tty_name

    @property
    def tty_name(self) -> str:
        return self._tty_name

    def start(self) -> "PtyModbusServer":
        self._master, self._slave = os.openpty()
        # Raw mode: no echo, no CR/LF translation; binary frames pass unchanged. The
        # slave end stays open here so the master never sees EIO between clients.
        tty.setraw(self._slave)
        self._tty_name = os.ttyname(self._slave)
        if self.link_path:
            tmp = f"{self.link_path}.{os.getpid()}.tmp"
            os.symlink(self._tty_name, tmp)
            os.replace(tmp, self.link_path)
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name="pty-modbus-server", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self.link_path and os.path.islink(self.link_path):
            if os.readlink(self.link_path) == self._tty_name:
                os.unlink(self.link_path)
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = None

    def __enter__(self) -> "PtyModbusServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- serving ------------------------------------------------------------------

    def _serve(self) -> None:
        buffer = b""
        last_rx = time.monotonic()
        advance = getattr(self.device, "advance", None)
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], self.tick_s)
            now = time.monotonic()
            if ready:
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    data = b""
                if data:
                    buffer += data
                    last_rx = now
            if advance is not None:
                advance()
            buffer = self._consume(buffer, now - last_rx >= self.frame_timeout_s)

    def _consume(self, buffer: bytes, silent: bool) -> bytes:
        """Handle every complete frame at the start of ``buffer``; return the rest."""
        while buffer:
            try:
                length = request_length(buffer)
            except UnknownFunction:
                if not silent:
                    return buffer  # its end is only known by the silence after it
                if crc_ok(buffer) and buffer[0] == self.slave_id:
                    self._send(encode_exception(buffer[0], buffer[1], ILLEGAL_FUNCTION))
                else:
                    self.dropped_bytes += len(buffer)
                return b""
            if length is None or len(buffer) < length:
                if silent:
                    self.dropped_bytes += len(buffer)
                    return b""
                return buffer
            frame, buffer = buffer[:length], buffer[length:]
            if not crc_ok(frame):
                # Lost sync (or line noise): drop everything up to the next silence.
                self.crc_errors += 1
                self.dropped_bytes += len(frame) + len(buffer)
                return b""
            self._handle(frame)
        return buffer

    def _handle(self, frame: bytes) -> None:
        slave, function = frame[0], frame[1]
        if slave not in (self.slave_id, BROADCAST_ADDRESS):
            return
        try:
            request = decode_request(frame)
            registers = ()
            if request.function in (WRITE_MULTIPLE_REGISTERS, READ_WRITE_MULTIPLE_REGISTERS):
                self.device.write_registers(request.write_address, request.values)
            if request.function in (
                READ_HOLDING_REGISTERS,
                READ_INPUT_REGISTERS,
                READ_WRITE_MULTIPLE_REGISTERS,
            ):
                registers = self.device.read_registers(request.read_address, request.read_count)
            response = encode_response(request, registers)
        except DeviceException as error:
            response = encode_exception(slave, function, error.code)
        self.requests_served += 1
        if slave != BROADCAST_ADDRESS:
            self._send(response)

    def _send(self, response: bytes) -> None:
        if not self.respond:
            return
        if self.corrupt_responses > 0:
            self.corrupt_responses -= 1
            response = response[:-1] + bytes([response[-1] ^ 0xFF])
        os.write(self._master, response)
