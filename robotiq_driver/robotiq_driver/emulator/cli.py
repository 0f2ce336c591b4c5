"""``gripper_emulator``: an emulated 2F-85 answering Modbus RTU on a pseudo-terminal.

    ros2 run robotiq_driver gripper_emulator --link /tmp/ttyRobotiq --object-width-m 0.04
    ros2 run robotiq_driver gripper --ros-args -p port:=/tmp/ttyRobotiq

Runs until SIGINT/SIGTERM. Not a ROS node: it stands where the gripper's serial cable
would be. A simulation that needs contact from physics embeds ``GripperEmulator`` with
its own ``FingerPlant`` and ``PtyModbusServer`` instead.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading

from ..gripper_registers import GripperScale
from .emulated_gripper import GripperEmulator, KinematicFingers
from .pty_modbus_server import PtyModbusServer


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="gripper_emulator", description=__doc__.split("\n")[0])
    parser.add_argument("--link", help="create this symlink to the pty (like socat's link=)")
    parser.add_argument("--slave-id", type=int, default=9, help="Modbus slave address (default 9)")
    parser.add_argument("--activation-time-s", type=float, default=1.0, help="activation duration (default 1.0)")
    parser.add_argument("--object-width-m", type=float, help="width of an object between the fingers")
    parser.add_argument("--initial-width-m", type=float, help="finger opening at power-up (default half open)")
    parser.add_argument("--fingers-meet-m", type=float, default=0.0,
                        help="opening where the fingertips touch: closing on nothing stops there and reports "
                             "an object (gOBJ 2), as some real units do (default 0: closes to 0, gOBJ 3)")
    args = parser.parse_args(argv)
    stroke = GripperScale().stroke_m
    for name in ("object_width_m", "initial_width_m", "fingers_meet_m"):
        value = getattr(args, name)
        if value is not None and not 0.0 <= value <= stroke:
            parser.error(f"--{name.replace('_', '-')} {value} is outside the 2F-85's opening 0..{stroke} m")
    if not 1 <= args.slave_id <= 247:
        parser.error(f"--slave-id {args.slave_id} is outside 1..247")
    if args.activation_time_s < 0:
        parser.error("--activation-time-s must be >= 0")
    if args.link and os.path.exists(args.link) and not os.path.islink(args.link):
        parser.error(f"--link {args.link} exists and is not a symlink; choose another path")
    return args


def main(argv=None) -> None:
    args = parse_args(argv)
    emulator = GripperEmulator(
        KinematicFingers(object_width_m=args.object_width_m, fingers_meet_m=args.fingers_meet_m),
        activation_time_s=args.activation_time_s,
        initial_width_m=args.initial_width_m,
    )
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    with PtyModbusServer(emulator, slave_id=args.slave_id, link_path=args.link) as server:
        where = server.tty_name + (f" (link {args.link})" if args.link else "")
        print(f"gripper_emulator: Robotiq 2F-85, slave {args.slave_id}, serving on {where}", flush=True)
        done.wait()
    print("gripper_emulator: stopped", flush=True)
    sys.exit(0)


if __name__ == "__main__":
    main()
