"""A pymodbus Modbus RTU serial server on a pseudo-terminal, serving one register device.

The wiring is what ``socat pty,link=A pty,link=B`` gives, with a thin byte-level
relay in the middle that can misbehave on purpose::

    client (driver, pyserial)                       pymodbus ModbusSerialServer (RTU)
      opens ``port`` (link_path) ── pty B ══ relay ══ pty A ── opens A's tty
                                              │
                              respond / corrupt_responses / unplug() / replug()

The server is pymodbus's: it does the RTU framing, the CRC and the function codes
(0x03 and 0x04 read, 0x10 write, 0x17 read/write; others get exception 0x01). Its
datastore is a ``SimDevice`` whose registers are the gripper's command block at
0x03E8 and status block at 0x07D0 and whose ``action`` hands every access to the
device: a read calls ``device.read_registers(address, count)``, a write
``device.write_registers(address, values)``; a ``DeviceException`` the device raises
becomes the Modbus exception response with its code. Unmapped addresses get 0x02 from
pymodbus before the device is asked. ``device.advance()`` is called every ``tick_s``
if the device has one.

As a Modbus slave does, the server stays silent on frames for other slave addresses
and on frames with a bad CRC, and executes broadcast (address 0) writes without
answering. For testing clients, the relay can emulate a gripper that stopped answering
(``respond = False``), a noisy line (``corrupt_responses = n``: the next n answers
reach the client with a flipped CRC byte), a loaded line where answers and requests
cross (``lose_requests = n``: the next n requests never reach the device;
``late_answers``: frames handed to the client right after its next request, as a
slow device's spare answer to an earlier retried request arrives) and an unplugged cable (``unplug()`` closes
the client's pty and removes the link; ``replug()`` brings a new pty back at the same
link, as a USB adapter re-enumerating under /dev/serial/by-id does).
"""

from __future__ import annotations

import asyncio
import logging
import os
import select
import threading
import tty

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer
from pymodbus.simulator import DataType, SimData, SimDevice

from ..gripper_registers import COMMAND_ADDRESS, REGISTER_COUNT, STATUS_ADDRESS
from .emulated_gripper import DeviceException

BROADCAST_ADDRESS = 0

# pymodbus logs line trouble at WARNING/ERROR; keep it off stderr unless the
# application configures logging.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())


class PtyModbusServer:
    def __init__(
        self,
        device,
        slave_id: int = 9,
        link_path: str | None = None,
        tick_s: float = 0.005,
        register_blocks: tuple[tuple[int, int], ...] = (
            (COMMAND_ADDRESS, REGISTER_COUNT),
            (STATUS_ADDRESS, REGISTER_COUNT),
        ),
    ):
        if not 1 <= slave_id <= 247:
            raise ValueError(f"slave_id {slave_id} out of range 1..247")
        self.device = device
        self.slave_id = slave_id
        self.link_path = link_path
        self.tick_s = tick_s
        self.register_blocks = register_blocks
        self.respond = True
        self.corrupt_responses = 0
        self.lose_requests = 0
        self.late_answers: list[bytes] = []
        self.requests_served = 0  # requests for this slave (or broadcast) pymodbus decoded
        self._client_master = self._client_slave = None
        self._server_master = self._server_slave = None
        self._tty_name = ""
        self._wake_r = self._wake_w = None
        self._relay: threading.Thread | None = None
        self._server_thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusSerialServer | None = None
        self._stop = threading.Event()
        self._fd_lock = threading.Lock()

    @property
    def port(self) -> str:
        """Path a client opens: the symlink if one was asked for, else the pty."""
        return self.link_path or self._tty_name

    @property
    def tty_name(self) -> str:
        return self._tty_name

    # -- lifecycle ----------------------------------------------------------------

    def start(self) -> "PtyModbusServer":
        self._stop.clear()
        self._server_master, self._server_slave = self._open_pty()
        self._wake_r, self._wake_w = os.pipe()
        self._plug()
        started = threading.Event()
        errors: list[BaseException] = []
        self._server_thread = threading.Thread(
            target=self._run_server, args=(os.ttyname(self._server_slave), started, errors),
            name="pymodbus-serial-server", daemon=True,
        )
        self._server_thread.start()
        if not started.wait(10.0) or errors:
            self.stop()
            raise RuntimeError(f"pymodbus serial server did not start: {errors[0] if errors else 'timeout'}")
        self._relay = threading.Thread(target=self._run_relay, name="pty-relay", daemon=True)
        self._relay.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._wake_w is not None:
            os.write(self._wake_w, b"x")
        if self._relay is not None:
            self._relay.join(timeout=2.0)
            self._relay = None
        if self._loop is not None and self._server_thread is not None:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._server_thread.join(timeout=5.0)
        self._server_thread = None
        self._unplug()
        for name in ("_server_master", "_server_slave", "_wake_r", "_wake_w"):
            fd = getattr(self, name)
            if fd is not None:
                os.close(fd)
                setattr(self, name, None)

    def __enter__(self) -> "PtyModbusServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def unplug(self) -> None:
        """The cable is pulled: the client's pty goes away (its reads and writes fail
        with EIO) and the link is removed. The gripper keeps its state."""
        self._unplug()
        os.write(self._wake_w, b"x")

    def replug(self) -> None:
        """A new pty appears at the same link (as a re-enumerated USB adapter)."""
        self._plug()
        os.write(self._wake_w, b"x")

    @staticmethod
    def _open_pty() -> tuple[int, int]:
        master, slave = os.openpty()
        os.set_blocking(master, False)  # the relay never blocks on a stale readiness
        # Raw mode: no echo, no CR/LF translation; binary frames pass unchanged. The
        # slave end stays open here so the master never sees EIO between clients.
        tty.setraw(slave)
        return master, slave

    def _plug(self) -> None:
        with self._fd_lock:
            if self._client_master is not None:
                return
            self._client_master, self._client_slave = self._open_pty()
            self._tty_name = os.ttyname(self._client_slave)
        if self.link_path:
            tmp = f"{self.link_path}.{os.getpid()}.tmp"
            os.symlink(self._tty_name, tmp)
            os.replace(tmp, self.link_path)

    def _unplug(self) -> None:
        if self.link_path and os.path.islink(self.link_path):
            if os.readlink(self.link_path) == self._tty_name:
                os.unlink(self.link_path)
        with self._fd_lock:  # the relay touches the client's fd only under this lock
            for fd in (self._client_master, self._client_slave):
                if fd is not None:
                    os.close(fd)
            self._client_master = self._client_slave = None

    # -- pymodbus server ------------------------------------------------------------

    def _device_model(self) -> SimDevice:
        blocks = [
            SimData(address, count=count, values=0, datatype=DataType.REGISTERS)
            for address, count in sorted(self.register_blocks)
        ]
        return SimDevice(self.slave_id, simdata=blocks, action=self._access)

    async def _access(self, function_code, start_address, address, count, registers, set_values):
        """pymodbus's hook on every register access: the device answers it."""
        try:
            if set_values is not None:
                self.device.write_registers(address, list(set_values))
            else:
                offset = address - start_address
                registers[offset : offset + count] = self.device.read_registers(address, count)
        except DeviceException as error:
            return ExcCodes(error.code)
        return None

    def _trace_pdu(self, sending: bool, pdu):
        """Requests for other slaves are dropped here, unanswered, as on a shared bus."""
        if sending:
            return pdu
        if pdu.dev_id not in (self.slave_id, BROADCAST_ADDRESS):
            return None
        self.requests_served += 1
        return pdu

    def _run_server(self, tty_name: str, started: threading.Event, errors: list) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._loop = loop

        async def serve() -> None:
            self._server = ModbusSerialServer(
                self._device_model(),
                framer=FramerType.RTU,
                port=tty_name,
                baudrate=115200,
                broadcast_enable=True,
                ignore_missing_devices=True,
                trace_pdu=self._trace_pdu,
            )
            await self._server.serve_forever(background=True)

        advance = getattr(self.device, "advance", None)

        def tick() -> None:
            advance()
            loop.call_later(self.tick_s, tick)

        try:
            loop.run_until_complete(serve())
        except BaseException as error:  # reported to start()
            errors.append(error)
            started.set()
            loop.close()
            return
        if advance is not None:
            loop.call_soon(tick)
        started.set()
        try:
            loop.run_forever()
        finally:
            try:
                loop.run_until_complete(self._server.shutdown())
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
            loop.close()
            self._loop = None

    # -- relay ----------------------------------------------------------------------

    def _run_relay(self) -> None:
        server = self._server_master
        while not self._stop.is_set():
            client = self._client_master
            watched = [server, self._wake_r] + ([client] if client is not None else [])
            ready, _, _ = select.select(watched, [], [], 0.5)
            if self._wake_r in ready:
                os.read(self._wake_r, 64)
                continue  # the set of fds may have changed
            if client is not None and client in ready:
                with self._fd_lock:
                    data = self._read(client) if self._client_master == client else b""
                if data and self.lose_requests > 0:
                    self.lose_requests -= 1
                elif data:
                    os.write(server, data)
                if data and self.late_answers:
                    self._to_client(self.late_answers.pop(0))
            if server in ready:
                data = self._read(server)
                if not data or not self.respond:
                    continue  # a silent gripper: the answer never reaches the line
                if self.corrupt_responses > 0:
                    self.corrupt_responses -= 1
                    data = data[:-1] + bytes([data[-1] ^ 0xFF])
                self._to_client(data)

    def _to_client(self, data: bytes) -> None:
        with self._fd_lock:
            if self._client_master is not None:
                try:
                    os.write(self._client_master, data)
                except OSError:
                    pass

    @staticmethod
    def _read(fd: int) -> bytes:
        try:
            return os.read(fd, 4096)
        except OSError:  # EAGAIN, or EIO while nobody holds the other end
            return b""
