"""The child processes of the demo and the soak: installed executables of the colcon
workspace (`installed`), each started in its own process group with its log in a file,
and all stopped together (`Processes`)."""
from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import time


def installed(package, name):
    prefix = pathlib.Path(os.environ.get("GRAVGRASP_ROOT", ".")) / "ros_ws" / "install"
    path = prefix / package / "lib" / package / name
    if not path.exists():
        raise SystemExit(f"demo: {path} is not installed; run 'make build'")
    return str(path)


class Processes:
    """Child processes in their own process groups, stopped with SIGINT then SIGKILL."""

    def __init__(self, log_dir):
        self.log_dir, self.procs = pathlib.Path(log_dir), []

    def start(self, name, cmd):
        log = open(self.log_dir / f"{name}.log", "wb")
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.procs.append((name, proc, log))
        return proc

    def wait_for(self, name, text, timeout_s):
        path = self.log_dir / f"{name}.log"
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if text in path.read_text(errors="replace"):
                return
            if any(n == name and p.poll() is not None for n, p, _ in self.procs):
                break
            time.sleep(0.1)
        raise SystemExit(f"demo: {name} did not become ready; its log {path} ends:\n"
                         + path.read_text(errors="replace")[-2000:])

    def stop(self):
        for sig, wait_s in ((signal.SIGINT, 10), (signal.SIGKILL, 5)):
            for _, proc, _ in self.procs:
                if proc.poll() is None:
                    try:
                        os.killpg(proc.pid, sig)
                    except ProcessLookupError:
                        pass
            for _, proc, _ in self.procs:
                try:
                    proc.wait(wait_s)
                except subprocess.TimeoutExpired:
                    pass
        for _, _, log in self.procs:
            log.close()
