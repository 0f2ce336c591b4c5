"""ArmProcess (ros/arm_process.py), the stack's supervisor of its arm-adapter process,
without ROS: it restarts an adapter that exits, reports how it ended, and a stop() that
arrives while an adapter is being started still ends that adapter."""
import sys
import threading
import time

from gravgrasp_detector.ros.arm_process import ArmProcess, exit_words

SLEEPER = [sys.executable, "-c", "import time; time.sleep(60)"]


def test_an_adapter_that_exits_is_reported_and_started_again():
    starts, exits = [], []
    arm = ArmProcess([sys.executable, "-c", "raise SystemExit(3)"], on_start=starts.append,
                     on_exit=lambda pid, code: exits.append((pid, code)), restart_after_s=0.05)
    arm.start()
    try:
        deadline = time.monotonic() + 30
        while len(exits) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        arm.stop()
    assert len(exits) >= 2, (starts, exits)
    assert [code for _, code in exits[:2]] == [3, 3]
    assert [pid for pid, _ in exits[:2]] == starts[:2] and starts[0] != starts[1]
    assert exit_words(3) == "exit code 3" and exit_words(-9) == "killed by SIGKILL"


class SlowToStart(ArmProcess):
    """Holds each start for a moment, so that stop() is sure to arrive during one."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.starting, self.spawned = threading.Event(), []

    def _spawn(self):
        self.starting.set()
        time.sleep(0.5)
        process = super()._spawn()
        self.spawned.append(process)
        return process


def test_a_stop_during_a_start_ends_the_adapter_being_started():
    arm = SlowToStart(SLEEPER, on_start=lambda pid: None, on_exit=lambda pid, code: None)
    arm.start()
    try:
        assert arm.starting.wait(10)
        arm.stop(timeout_s=5.0)
        assert arm.spawned, "stop() returned before the start it interrupted had finished"
        assert [p.poll() is not None for p in arm.spawned] == [True] * len(arm.spawned), \
            "an adapter started during stop() outlived it"
        arm._thread.join(5)
        assert not arm._thread.is_alive(), "the supervisor went on after stop()"
        assert len(arm.spawned) == 1, "started again after stop()"
    finally:
        for p in arm.spawned:
            if p.poll() is None:
                p.kill()
