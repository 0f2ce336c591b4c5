"""Helpers for tests that talk ROS 2 over real DDS on loopback.

- Every pytest run gets its own ROS_DOMAIN_ID (conftest sets it before rclpy starts),
  so parallel runs on one machine never hear each other.
- `RosProcess` starts an installed executable (install/<pkg>/lib/<pkg>/<exe>, the file
  `ros2 run` starts) as a real process and stops it, its children included.
- `spin_until` / `wait_for_*` wait on the ROS graph or on received data, never on a
  blind sleep: discovery takes up to ~3 s here.
"""
from __future__ import annotations

import os
import pathlib
import re
import signal
import subprocess
import tempfile
import threading
import time

import rclpy

from sim_bridge.ros.service_call import call_blocking

ROOT = pathlib.Path(__file__).resolve().parents[2]
INSTALL = ROOT / "ros_ws" / "install"
DOMAIN_LOCK_DIR = pathlib.Path(tempfile.gettempdir()) / "gravgrasp-ros-domains"


def claim_domain_id() -> int:
    """A ROS_DOMAIN_ID in 1..101 that no other live pytest run on this machine holds.

    Claimed by creating a lock file named after the id holding our pid; stale locks
    (their pid is gone) are taken over."""
    DOMAIN_LOCK_DIR.mkdir(exist_ok=True)
    start = os.getpid() % 101
    for offset in range(101):
        domain = (start + offset) % 101 + 1
        lock = DOMAIN_LOCK_DIR / str(domain)
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            try:
                holder = int(lock.read_text() or 0)
                os.kill(holder, 0)
                continue  # held by a live process
            except (ValueError, ProcessLookupError, PermissionError, FileNotFoundError):
                lock.unlink(missing_ok=True)
                try:
                    fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
                except FileExistsError:
                    continue
        os.write(fd, str(os.getpid()).encode())
        os.close(fd)
        return domain
    raise RuntimeError("no free ROS_DOMAIN_ID in 1..101; remove stale files in " + str(DOMAIN_LOCK_DIR))


def release_domain_id(domain: int) -> None:
    lock = DOMAIN_LOCK_DIR / str(domain)
    try:
        if int(lock.read_text()) == os.getpid():
            lock.unlink()
    except (OSError, ValueError):
        pass


def executable(package: str, name: str) -> pathlib.Path:
    path = INSTALL / package / "lib" / package / name
    if not path.exists():
        raise FileNotFoundError(f"{path} is not installed; run 'make build'")
    return path


def ros_args(params: dict | None = None, remap: dict | None = None) -> list[str]:
    """`--ros-args -p name:=value -r from:=to` for a node's command line."""
    out = []
    for name, value in (params or {}).items():
        if isinstance(value, bool):
            value = "true" if value else "false"
        elif isinstance(value, (list, tuple)):
            value = "[" + ",".join(repr(v) if isinstance(v, str) else str(v) for v in value) + "]"
        out += ["-p", f"{name}:={value}"]
    for source, target in (remap or {}).items():
        out += ["-r", f"{source}:={target}"]
    return ["--ros-args", *out] if out else []


class RosProcess:
    """An installed ROS executable running as a child process, output to a log file."""

    def __init__(self, package: str, name: str, args=(), params=None, remap=None,
                 env=None, log_dir: pathlib.Path | None = None, cmd: list[str] | None = None):
        """Start install/<package>/lib/<package>/<name>, or `cmd` if given."""
        self.package, self.name = package, name
        self.cmd = cmd or [str(executable(package, name)), *map(str, args)]
        self.cmd += ros_args(params, remap)
        log_dir = log_dir or pathlib.Path(tempfile.mkdtemp(prefix="gravgrasp-test-"))
        self.log_path = log_dir / f"{package}-{name}-{os.getpid()}-{id(self)}.log"
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            self.cmd, stdout=self._log, stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
            start_new_session=True)  # own process group: stop() reaches its children

    def output(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")

    def wait_for_output(self, pattern: str, timeout_s: float = 20.0) -> re.Match:
        deadline = time.monotonic() + timeout_s
        regex = re.compile(pattern)
        while time.monotonic() < deadline:
            match = regex.search(self.output())
            if match:
                return match
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise AssertionError(
            f"{self.name}: no output matching {pattern!r} within {timeout_s} s "
            f"(exit code {self.proc.poll()}); output:\n{self.output()[-3000:]}")

    def wait_exit(self, timeout_s: float = 20.0) -> int:
        return self.proc.wait(timeout=timeout_s)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout_s: float = 10.0) -> int:
        """SIGINT (a ROS node's clean shutdown), then SIGTERM, then SIGKILL."""
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if self.proc.poll() is not None:
                break
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                break
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                continue
        # Its children (the stack's arm adapter) got the same signal and may end a moment
        # after it on a loaded machine: give them that moment before group_alive() judges.
        deadline = time.monotonic() + timeout_s
        while self.group_alive() and time.monotonic() < deadline:
            time.sleep(0.05)
        self._log.close()
        return self.proc.returncode

    def group_alive(self) -> bool:
        """True if any process of this executable's process group still runs."""
        try:
            os.killpg(self.proc.pid, 0)
            return True
        except ProcessLookupError:
            return False


def spin_until(node, predicate, timeout_s: float = 15.0, executor=None) -> bool:
    """Spin `node` until predicate() is true or the timeout passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        if executor is not None:
            executor.spin_once(timeout_sec=0.05)
        else:
            rclpy.spin_once(node, timeout_sec=0.05)
    return predicate()


def wait_for_publisher(node, topic: str, timeout_s: float = 15.0) -> bool:
    return spin_until(node, lambda: node.count_publishers(topic) > 0, timeout_s)


def wait_for_subscriber(node, topic: str, timeout_s: float = 15.0) -> bool:
    return spin_until(node, lambda: node.count_subscribers(topic) > 0, timeout_s)


def call_service(node, client, request, timeout_s: float = 15.0, resend_s: float | None = None):
    """Wait for the service, call it, spin until the response; raise on timeout.

    rmw_fastrtps drops a response when the server has not yet matched the client's reply
    reader (it waits 100 ms; ros2/rmw_fastrtps#842), which can happen to a just-created
    client on a loaded machine. So the call waits until this node sees the server's reply
    writer, and `resend_s` (only for requests that are safe to repeat) sends the request
    again after that long without an answer."""
    if not client.wait_for_service(timeout_sec=timeout_s):
        raise AssertionError(f"service {client.srv_name} not available within {timeout_s} s")
    reply_topic = f"rr{client.service_name}Reply"  # the DDS topic of the replies (resolved name)
    spin_until(node, lambda: node.get_publishers_info_by_topic(reply_topic, no_mangle=True), min(timeout_s, 10.0))
    deadline = time.monotonic() + timeout_s
    futures = [client.call_async(request)]
    while time.monotonic() < deadline:
        step = deadline - time.monotonic() if resend_s is None else min(resend_s, deadline - time.monotonic())
        if spin_until(node, lambda: any(f.done() for f in futures), step):
            return next(f for f in futures if f.done()).result()
        if resend_s is not None and time.monotonic() < deadline:
            futures.append(client.call_async(request))
    raise AssertionError(f"service {client.srv_name} did not answer within {timeout_s} s ({len(futures)} request(s) "
                         "sent); a 'failed to send response' in the server's log means a lost reply (rmw_fastrtps#842)")


def call_spun(client, request, timeout_s: float = 30.0, resend_s: float | None = None):
    """The response of a client whose node another thread spins; raises ServiceTimeout (a
    TimeoutError) and so fails the test. `resend_s`: see call_blocking (only for requests
    that are safe to repeat)."""
    return call_blocking(client, request, timeout_s, wait_for_service_s=15.0, resend_s=resend_s)


class BackgroundSpin:
    """Spin a node in a MultiThreadedExecutor thread, for tests that call services from
    several threads at once (rclpy.spin_once on one node from two threads is unsafe)."""

    def __init__(self, node, threads: int = 4):
        from rclpy.executors import MultiThreadedExecutor
        self.node = node
        self.executor = MultiThreadedExecutor(num_threads=threads)
        self.executor.add_node(node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def call(self, client, request, timeout_s: float = 30.0, resend_s: float | None = None):
        return call_spun(client, request, timeout_s, resend_s)

    def shutdown(self):
        self.executor.shutdown()


def wait_until(predicate, timeout_s: float) -> bool:
    """Poll a predicate whose data a background executor updates."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not predicate():
        time.sleep(0.02)
    return bool(predicate())
