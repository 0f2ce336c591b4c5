"""The ur_arm node as its own process, with the ur_rtde stand-in (fake_rtde) in place of a
robot: what the stack starts as its arm adapter (`stack.arm_command`) in the tests and
the arm soak. Takes the ur_arm node's ROS arguments.

Environment (all optional):
    FAKE_UR_DROP_EVERY_S   drop the RTDE link this often (ur_rtde then reconnects by itself)
    FAKE_UR_DROP_FOR_S     for this long (default 0.3 s)
    FAKE_UR_RECONNECT_WAIT_S  a command sent during a drop waits this long for ur_rtde's own
                           reconnect, then is sent again (fake_rtde's reconnect_wait_s; default 0)
    FAKE_UR_LOG            append one JSON line per motion the controller ran, and per request
                           answered, for the soak's checks
"""
import json
import math
import os
import pathlib
import sys
import threading
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from fake_rtde import TCP_2F85, FakeURController  # noqa: E402
from gravgrasp_detector.ros.interface import run_node  # noqa: E402
from gravgrasp_detector.ros.ur_arm_node import URArmNode  # noqa: E402


def main():
    # The TCP starts at task (0.15, 0.15, 0.30), pointing down, for the sample cell's base
    # (0.15, -0.45, 0): inside its protective box.
    ur = FakeURController(tcp_pose=(0.0, 0.6, 0.3, math.pi, 0.0, 0.0))
    log_path = os.environ.get("FAKE_UR_LOG")
    log_lock = threading.Lock()

    def record(entry):
        if log_path:
            with log_lock, open(log_path, "a") as f:
                f.write(json.dumps(entry) + "\n")

    ur.reconnect_wait_s = float(os.environ.get("FAKE_UR_RECONNECT_WAIT_S", "0"))
    drop_every = float(os.environ.get("FAKE_UR_DROP_EVERY_S", "0"))
    drop_for = float(os.environ.get("FAKE_UR_DROP_FOR_S", "0.3"))

    def drops():
        while True:
            time.sleep(drop_every)
            ur.drop_link(drop_for)
            record({"t": time.time(), "event": "link dropped", "for_s": drop_for})

    if drop_every > 0:
        threading.Thread(target=drops, daemon=True).start()

    class Node(URArmNode):
        def __init__(self):
            super().__init__(connect=ur.connect)
            self.get_logger().info("fake_ur_arm: the ur_rtde stand-in in place of a robot")

        def _on_move(self, request, response):
            t0, t0_mono = time.time(), time.monotonic()
            n = len(ur.motions)
            response = super()._on_move(request, response)
            record({"t": t0, "t0_mono": t0_mono, "t1_mono": time.monotonic(), "event": "request", "check_only": bool(request.check_only),
                    "success": bool(response.success), "reachable": bool(response.reachable),
                    "message": response.message, "deadline": request.deadline.sec + request.deadline.nanosec * 1e-9,
                    "target_base": self.arm.to_base(self._target(request.target)) if response.reachable else None,
                    "pinch_point_base": ur.tcp_pose_in(TCP_2F85), "motions": len(ur.motions) - n})
            return response

    def motions():  # every motion the controller ran, with who asked and its TCP
        seen = 0
        while True:
            time.sleep(0.05)
            while seen < len(ur.motions):
                m = ur.motions[seen]
                record({"t": time.time(), "event": "motion", "t0_mono": m["t0"], "tcp": m["tcp"],
                        "target": m["target"], "by_current_interface": m["by"] is node_ref[0].arm._control})
                seen += 1

    node_ref = [None]

    def make():
        node_ref[0] = Node()
        threading.Thread(target=motions, daemon=True).start()
        return node_ref[0]

    return run_node("ur_arm", make, ValueError, threads=4)


if __name__ == "__main__":
    sys.exit(main())
