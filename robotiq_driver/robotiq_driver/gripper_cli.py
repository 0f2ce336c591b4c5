"""``gripper_cli``: drive a Robotiq 2F-85 by hand from a terminal at the robot.

    ros2 run robotiq_driver gripper_cli status   --port /dev/ttyUSB0
    ros2 run robotiq_driver gripper_cli activate --port /dev/ttyUSB0
    ros2 run robotiq_driver gripper_cli close    --port /dev/ttyUSB0 --force-n 60
    ros2 run robotiq_driver gripper_cli open     --port /dev/ttyUSB0
    ros2 run robotiq_driver gripper_cli move --position-m 0.04 --speed-mps 0.05 --port /dev/ttyUSB0
    ros2 run robotiq_driver gripper_cli calibrate --port /dev/ttyUSB0 --force-n 40   # empty hand!

Talks to the gripper directly through the driver (no ROS): stop the gripper node
first, it holds the port. Motions wait until the fingers stop and print how they
ended. On any failure it prints one line, ``gripper_cli: error: ...``, and exits 1
(2 for a bad command line).
"""

from __future__ import annotations

import argparse
import sys

from . import grip_calibration
from .gripper_client import GripperError, Robotiq2F85, describe_motion_end
from .gripper_registers import BAUDRATE, SLAVE_ID, ActivationStatus, ObjectStatus

DEFAULT_SPEED_MPS = 0.1
DEFAULT_FORCE_N = 40.0
OBJECT_TEXT = {
    ObjectStatus.MOVING: "fingers moving (or no motion requested yet)",
    ObjectStatus.CONTACT_OPENING: "stopped on an object while opening",
    ObjectStatus.CONTACT_CLOSING: "stopped on an object while closing",
    ObjectStatus.AT_POSITION: "at the requested position, no object",
}
ACTIVATION_TEXT = {
    ActivationStatus.RESET: "not activated (in reset)",
    ActivationStatus.ACTIVATING: "activation in progress",
    ActivationStatus.UNUSED: "gSTA 2 (not used)",
    ActivationStatus.ACTIVATED: "activated",
}


def _connection_options(parser: argparse.ArgumentParser, suppress: bool) -> None:
    """The port options, accepted before or after the command."""
    default = (lambda value: argparse.SUPPRESS) if suppress else (lambda value: value)
    parser.add_argument("--port", default=default("/dev/ttyUSB0"),
                        help="serial device (default /dev/ttyUSB0; prefer /dev/serial/by-id/...)")
    parser.add_argument("--slave-id", type=int, default=default(SLAVE_ID), help=f"Modbus slave id (default {SLAVE_ID})")
    parser.add_argument("--baud", type=int, default=default(BAUDRATE), help=f"baud rate (default {BAUDRATE})")
    parser.add_argument("--timeout-s", type=float, default=default(0.1),
                        help="answer timeout per Modbus attempt, s (default 0.1)")
    parser.add_argument("--retries", type=int, default=default(2), help="retries per Modbus call (default 2)")


def _motion_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--speed-mps", type=float, default=DEFAULT_SPEED_MPS,
                        help=f"finger speed, 0.020..0.150 m/s (default {DEFAULT_SPEED_MPS})")
    parser.add_argument("--force-n", type=float, default=DEFAULT_FORCE_N,
                        help=f"grip force, 20..235 N (default {DEFAULT_FORCE_N:g})")
    parser.add_argument("--wait-s", type=float, default=6.0,
                        help="longest wait for the fingers to stop, s (default 6; a full stroke at 20 mm/s is 4.3 s)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gripper_cli",
        description="Drive a Robotiq 2F-85 by hand: activate, open, close, move, status (no ROS; "
        "stop the gripper node first, it holds the port).",
    )
    _connection_options(parser, suppress=False)
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    common = argparse.ArgumentParser(add_help=False)
    _connection_options(common, suppress=True)

    activate = commands.add_parser("activate", parents=[common],
                                   help="reset and activate if not active (the fingers open fully)")
    activate.add_argument("--timeout-activation-s", type=float, default=5.0,
                          help="longest wait for the activation, s (default 5)")
    activate.add_argument("--force", action="store_true", help="reset and activate even if already active")
    for name, text in (("open", "open fully"), ("close", "close (stops on an object)")):
        _motion_options(commands.add_parser(name, parents=[common], help=text))
    _motion_options(commands.add_parser(
        "calibrate", parents=[common],
        help="with nothing in the hand: open, close on nothing, open; print where the fingers stop "
             "(the executor's gripper_empty_closed_m; use the executor's grip speed and force)"))
    move = commands.add_parser("move", parents=[common], help="move the fingers to an opening")
    move.add_argument("--position-m", type=float, required=True, help="finger opening, 0..0.085 m")
    _motion_options(move)
    commands.add_parser("status", parents=[common], help="print the gripper's status registers")
    return parser


def format_status(gripper: Robotiq2F85, state) -> str:
    width_mm = gripper.width_m(state) * 1e3
    lines = [
        f"{gripper.port}, slave {gripper.slave_id}: {ACTIVATION_TEXT[ActivationStatus(state.activation_status)]}"
        f" (gACT {int(state.activated)}, gSTA {int(state.activation_status)}, gGTO {int(state.go)})",
        f"opening {width_mm:.1f} mm ({state.position} counts; requested {state.requested} counts), "
        f"current {state.current_a:.2f} A",
        f"object: {OBJECT_TEXT[ObjectStatus(state.object_status)]} (gOBJ {int(state.object_status)})",
        f"fault: 0x{state.fault:02X} {state.fault_text}" if state.fault else "fault: none",
    ]
    if state.controller_fault:
        lines.append(f"controller fault (kFLT): 0x{state.controller_fault:X}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> str:
    """Carry out the command; return what to print. Raises on failure."""
    with Robotiq2F85(args.port, args.slave_id, args.baud, args.timeout_s, args.retries) as gripper:
        if args.command == "status":
            return format_status(gripper, gripper.read_state())
        if args.command == "activate":
            faulted = gripper.read_state().fault != 0
            state = gripper.activate(args.timeout_activation_s, force=args.force or faulted)
            return f"activated, opening {gripper.width_m(state) * 1e3:.1f} mm"
        if args.command == "calibrate":
            cal = grip_calibration.calibrate_empty_closed(gripper, args.speed_mps, args.force_n, args.wait_s)
            return (f"{cal.describe()} at {args.speed_mps:g} m/s, {args.force_n:g} N; for the executor: "
                    f"-p gripper_empty_closed_m:={cal.width_m:.4f}")
        target = {"open": gripper.scale.stroke_m, "close": 0.0}.get(args.command)
        if target is None:
            target = args.position_m
        state = gripper.move_and_wait(target, args.speed_mps, args.force_n, timeout_s=args.wait_s)
        return describe_motion_end(state, gripper.width_m(state))


def main(argv=None) -> None:
    parser = build_parser()
    args = parser.parse_args(argv)
    # Options given only before the command are in args already; the subparser's
    # suppressed defaults never overwrite them.
    for name, value in (("timeout_s", args.timeout_s), ("retries", args.retries), ("slave_id", args.slave_id)):
        if name == "timeout_s" and not value > 0:
            parser.error("--timeout-s must be > 0")
        if name == "retries" and value < 0:
            parser.error("--retries must be >= 0")
        if name == "slave_id" and not 1 <= value <= 247:
            parser.error(f"--slave-id {value} is outside 1..247")
    try:
        print(run(args), flush=True)
    except (GripperError, ValueError) as error:
        print(f"gripper_cli: error: {error}", file=sys.stderr, flush=True)
        sys.exit(1)
    except KeyboardInterrupt:
        print("gripper_cli: interrupted", file=sys.stderr)
        sys.exit(130)


if __name__ == "__main__":
    main()
