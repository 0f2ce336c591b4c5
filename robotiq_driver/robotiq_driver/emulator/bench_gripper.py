"""`ros2 run robotiq_driver bench_gripper`: Modbus RTU round trips to the emulator on a pty.

Measures, with the driver and the emulator in one process (two threads):
- a status read (FC03, 3 registers: 8-byte request, 11-byte answer),
- a command write (FC16, 3 registers: 15-byte request, 8-byte answer),
- the wall time of a full close (activation excluded) at 150 mm/s onto a 40 mm object,
  against the 0.30 s the fingers need at that speed.
A pty has no baud rate: on a real RS-485 line at 115200 baud the 19 bytes of a status
read alone take 1.65 ms on the wire, which this does not include (printed for scale).
Prints `name=value` lines; the last is `status_reads_per_s=<n>`.
"""

from __future__ import annotations

import argparse
import statistics
import time

from ..gripper_client import Robotiq2F85
from ..gripper_registers import GripperCommand
from .emulated_gripper import GripperEmulator, KinematicFingers
from .pty_modbus_server import PtyModbusServer


def _timed(fn, n):
    times = []
    for _ in range(n):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return times


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="bench_gripper", description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=2000, help="transactions per measurement (default 2000)")
    args = parser.parse_args(argv)
    if args.n < 10:
        parser.error("--n must be at least 10")
    emulator = GripperEmulator(KinematicFingers(object_width_m=0.040), activation_time_s=0.1)
    with PtyModbusServer(emulator) as server, Robotiq2F85(server.port, timeout_s=0.5) as gripper:
        gripper.activate(timeout_s=5.0)
        reads = sorted(_timed(gripper.read_state, args.n))
        hold = GripperCommand(activate=True, go=False)
        writes = sorted(_timed(lambda: gripper.write_command(hold), args.n))
        start = time.perf_counter()
        gripper.move_and_wait(0.0, 0.150, 40.0, timeout_s=5.0)
        close_s = time.perf_counter() - start
        retries = gripper.modbus.failed_attempts

    def p(values, q):
        return values[min(len(values) - 1, int(q * len(values)))] * 1e3

    print(f"status_read_ms_median={statistics.median(reads) * 1e3:.3f}")
    print(f"status_read_ms_p99={p(reads, 0.99):.3f}")
    print(f"command_write_ms_median={statistics.median(writes) * 1e3:.3f}")
    print(f"command_write_ms_p99={p(writes, 0.99):.3f}")
    print(f"status_read_wire_ms_at_115200={19 * 10 / 115200 * 1e3:.3f}")
    print(f"close_on_40mm_object_s={close_s:.3f}")
    print(f"close_on_40mm_object_fingers_only_s={0.045 / 0.150:.3f}")
    print(f"failed_attempts={retries}")
    print(f"status_reads_per_s={len(reads) / sum(reads):.0f}")


if __name__ == "__main__":
    main()
