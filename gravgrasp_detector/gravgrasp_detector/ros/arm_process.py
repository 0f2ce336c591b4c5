"""The arm adapter as a child process of the stack, supervised: started, watched, started
again after it exits. No rclpy.

Why a process of its own: ur_rtde is a native library that reconnects by itself, and its
users report the process dying of SIGSEGV when that reconnect fails. In the stack's own
process such a crash would also end tsdf, detect and execute, and nobody would report it.
As a child, its death is seen at once (the wait returns; a DDS graph would notice a killed
process only when its participant lease runs out), the executor is told and disarms, and
a new adapter is started.
"""
from __future__ import annotations

import ctypes
import signal
import subprocess
import threading
from typing import Callable

_PR_SET_PDEATHSIG = 1


def _die_with_parent():
    """In the child: SIGTERM when the stack dies, however it dies (Linux)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


def exit_words(code: int) -> str:
    """A child's exit status in words: 'exit code 2', 'killed by SIGSEGV'."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class ArmProcess:
    """Runs `command` and starts it again `restart_after_s` after it exits, until stop().
    `on_start(pid)` and `on_exit(pid, code)` are called from the watching thread."""

    def __init__(self, command: list[str], on_start: Callable[[int], None], on_exit: Callable[[int, int], None],
                 restart_after_s: float = 2.0):
        if not command:
            raise ValueError("the arm adapter's command is empty")
        self.command = list(command)
        self.on_start, self.on_exit = on_start, on_exit
        self.restart_after_s = restart_after_s
        self._stopping = threading.Event()
        self._lock = threading.Lock()  # a start and stop() never interleave
        self._process: subprocess.Popen | None = None
        self._thread = threading.Thread(target=self._run, name="arm-process", daemon=True)

    @property
    def pid(self) -> int | None:
        process = self._process
        return None if process is None else process.pid

    def start(self):
        self._thread.start()

    def _spawn(self) -> subprocess.Popen:
        return subprocess.Popen(self.command, preexec_fn=_die_with_parent)

    def _run(self):
        while True:
            # Checked and started under the lock: a stop() arriving between the check and the
            # start would otherwise see the old process and leave the new one running.
            with self._lock:
                if self._stopping.is_set():
                    return
                try:
                    process = self._process = self._spawn()
                except OSError as e:
                    process, error = None, e
            if process is None:
                self.on_exit(-1, 127)
                print(f"stack: cannot start the arm adapter {self.command[0]}: {error}", flush=True)
                self._stopping.wait(self.restart_after_s)
                continue
            self.on_start(process.pid)
            code = process.wait()
            if self._stopping.is_set():
                return
            self.on_exit(process.pid, code)
            self._stopping.wait(self.restart_after_s)

    def stop(self, timeout_s: float = 5.0):
        """End the adapter (SIGINT, as Ctrl-C; then SIGKILL) and do not start it again."""
        with self._lock:
            self._stopping.set()
            process = self._process
        if process is not None and process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
