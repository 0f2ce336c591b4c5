"""Soak of the UR cell's stack with the stand-in arm: grasps back to back for a while, the
RTDE link dropped every `--drop-every-s` (ur_rtde then reconnects by itself, restarting
its script with the pendant's TCP), both cores loaded by busy processes. Checks, from the
stand-in controller's own record (tests/support/fake_ur_arm.py, FAKE_UR_LOG):

  - no motion outside a request that ur_arm accepted: a move ur_rtde sent again after a
    refused or abandoned request, or one nobody asked for, would start outside every
    accepted request's window;
  - no SUCCESS whose pinch point (the flange times tcp_in_flange, as the stand-in
    measures it) is more than 5 mm from the commanded target.

Prints its figures, then `arm_soak_ok=1` (or 0) last. `make soak-arm` runs it for 5 minutes.

    python tests/support/arm_soak.py --duration-s 300 --drop-every-s 30 --out out/soak-arm
"""
import argparse
import collections
import json
import math
import os
import pathlib
import subprocess
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import rclpy  # noqa: E402
import ros_testing  # noqa: E402
from gravgrasp_msgs.srv import ExecuteGrasp  # noqa: E402
from std_srvs.srv import SetBool  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
UR_CELL = ROOT / "gravgrasp_detector" / "cells" / "ur5e_2f85_realsense.yaml"
SUCCESS_LIMIT_M = 0.005
GRASPS = [(0.15, 0.15, 0.08), (0.10, 0.20, 0.06), (0.20, 0.10, 0.10), (0.12, 0.12, 0.07)]


def check(log_path: pathlib.Path) -> tuple[dict, list[str]]:
    """(figures, violations) from the stand-in's record."""
    entries = [json.loads(line) for line in log_path.read_text().splitlines()] if log_path.exists() else []
    requests = [e for e in entries if e["event"] == "request" and not e["check_only"]]
    motions = [e for e in entries if e["event"] == "motion"]
    accepted = [(e["t0_mono"], e["t1_mono"]) for e in requests if e["motions"] > 0 or e["success"]]
    problems = []
    for m in motions:
        if not any(t0 - 0.05 <= m["t0_mono"] <= t1 + 0.05 for t0, t1 in accepted):
            problems.append(f"a motion started at {m['t0_mono']:.2f} s outside every accepted request (target "
                            f"{[round(v, 3) for v in m['target'][:3]]}, TCP {m['tcp']})")
    worst = 0.0
    for r in requests:
        if r["success"]:
            off = math.dist(r["pinch_point_base"][:3], r["target_base"][:3])
            worst = max(worst, off)
            if off > SUCCESS_LIMIT_M:
                problems.append(f"SUCCESS with the pinch point {off * 1000:.1f} mm from the target: {r['message']}")
    figures = {"arm_requests": len(requests), "arm_successes": sum(r["success"] for r in requests),
               "arm_motions": len(motions), "link_drops": sum(e["event"] == "link dropped" for e in entries),
               "worst_success_offset_mm": round(worst * 1000, 2)}
    return figures, problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration-s", type=float, default=300.0)
    parser.add_argument("--drop-every-s", type=float, default=30.0)
    parser.add_argument("--load-processes", type=int, default=2, help="busy processes beside the stack")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "soak-arm")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    log = args.out / "arm.jsonl"
    log.unlink(missing_ok=True)
    domain = ros_testing.claim_domain_id()
    os.environ["ROS_DOMAIN_ID"] = str(domain)  # read by rclpy.init

    processes, load = [], []
    rclpy.init()
    node = rclpy.create_node("arm_soak")
    spin = ros_testing.BackgroundSpin(node)
    codes = collections.Counter()
    try:
        link = str(args.out / "ttyGripper")
        processes.append(ros_testing.RosProcess("robotiq_driver", "gripper_emulator", log_dir=args.out, args=[
            "--link", link, "--object-width-m", "0.05", "--activation-time-s", "0.1"]))
        stack = ros_testing.RosProcess("gravgrasp_detector", "stack", log_dir=args.out, env={
            "FAKE_UR_LOG": str(log), "FAKE_UR_DROP_EVERY_S": str(args.drop_every_s),
            "FAKE_UR_RECONNECT_WAIT_S": "1.0"}, cmd=[
            str(ros_testing.executable("gravgrasp_detector", "stack")), "--ros-args", "--params-file", str(UR_CELL),
            "-p", f"stack:arm_command:={sys.executable} {ROOT / 'tests' / 'support' / 'fake_ur_arm.py'}",
            "-p", f"execute:gripper_port:={link}", "-p", "execute:max_tsdf_age_s:=0.0",
            "-p", "execute:gripper_empty_closed_m:=0.0", "-p", "execute:gripper_reply_timeout_s:=0.5",
            "-p", "ur_arm:max_speed_mps:=0.25", "-p", "execute:max_speed_mps:=0.25",
            "-p", "execute:approach_speed_mps:=0.05", "-p", "ur_arm:reconnect_period_s:=0.5"])
        processes.append(stack)
        stack.wait_for_output("execute ready", timeout_s=300)
        stack.wait_for_output("ur_arm ready", timeout_s=120)
        load = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.load_processes)]
        arm_execute = node.create_client(SetBool, "execute/arm")
        arm_ur = node.create_client(SetBool, "ur_arm/arm")
        execute = node.create_client(ExecuteGrasp, "execute_grasp")
        t_end = time.monotonic() + args.duration_s
        i = 0
        while time.monotonic() < t_end:
            spin.call(arm_ur, SetBool.Request(data=True), 30, resend_s=5.0)  # an operator re-arming after a fault
            spin.call(arm_execute, SetBool.Request(data=True), 30, resend_s=5.0)
            request = ExecuteGrasp.Request()
            request.header.frame_id = "task"
            p, q = request.grasp.pose.position, request.grasp.pose.orientation
            p.x, p.y, p.z = GRASPS[i % len(GRASPS)]
            q.x, q.w = 1.0, 0.0
            result = spin.call(execute, request, 120)
            codes[result.result_code] += 1
            print(f"grasp {i + 1}: code {result.result_code}: {result.message[:160]}", flush=True)
            i += 1
        if not stack.alive():
            print("ERROR: the stack died", flush=True)
            return _finish({}, ["the stack died"], codes)
    finally:
        for proc in load:
            proc.kill()
        spin.shutdown()
        for proc in reversed(processes):
            proc.stop()
        node.destroy_node()
        rclpy.try_shutdown()
        ros_testing.release_domain_id(domain)
    time.sleep(0.2)
    figures, problems = check(log)
    return _finish(figures, problems, codes)


def _finish(figures, problems, codes) -> int:
    names = {v: k for k, v in vars(ExecuteGrasp.Response).items() if k.isupper() and isinstance(v, int)}
    print("executions: " + ", ".join(f"{names.get(c, c)} {n}" for c, n in sorted(codes.items())))
    for name, value in figures.items():
        print(f"{name}={value}")
    for problem in problems:
        print(f"ERROR: {problem}")
    ok = bool(figures) and not problems and figures.get("arm_successes", 0) > 0
    print(f"arm_soak_ok={int(ok)}", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
