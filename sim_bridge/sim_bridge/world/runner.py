"""Real time for the simulated cell: `RealTimeRunner` steps a SimWorld in its own thread on
the wall clock, and `SimFingerPlant` lets the Robotiq emulator drive the simulated fingers
(robotiq_driver's FingerPlant) without waiting for the physics. Uses only SimWorld's
public interface."""

from __future__ import annotations

import threading
import time

import numpy as np

from robotiq_driver.emulator.emulated_gripper import FingerReading

from .sim_world import SimWorld


class SimFingerPlant:
    """robotiq_driver.emulator.emulated_gripper.FingerPlant backed by a SimWorld: the emulator's
    commanded opening, speed and force drive the simulated actuator; the reading is the
    simulated driver angle as an opening, `blocked` when the fingers stopped on an object
    short of the target, and 0.10 A while they move (0 once stopped: the 2F-85's drive is
    self-locking).

    With `advances_time`, `advance(dt)` commands the world and simulates dt itself. Without,
    a RealTimeRunner steps the world, and `advance` never waits for it: the command goes
    into a mailbox the runner applies before its next chunk, and the reading is the one the
    runner took after its last chunk (a Modbus answer must not wait for the physics). Until
    the runner has taken a reading for the latest command, the fingers read as moving.
    """

    MOVING_CURRENT_A = 0.10

    # With `advances_time` each `advance(dt)` also simulates dt (the emulator's clock
    # drives the sim); without, a RealTimeRunner steps the world.

    def __init__(self, world: SimWorld, advances_time: bool = True):
        self.world = world
        self.advances_time = advances_time
        self.last_call_wall_s = None
        self._pending = None  # (target m, speed m/s, force N): the emulator's latest command
        self._applied = None  # the command the world runs (what the runner last applied)
        self._snapshot = None  # (the command it answers, FingerReading)

    def _reading(self, width, state):
        return FingerReading(width, state == "blocked", self.MOVING_CURRENT_A if state == "moving" else 0.0)

    def advance(self, dt_s, width_m, target_width_m, speed_mps, force_n):
        self.last_call_wall_s = time.monotonic()
        command = (float(target_width_m), float(speed_mps), float(force_n))
        if self.advances_time:
            self.world.command_fingers(*command)
            if dt_s > 0:
                self.world.advance(dt_s)
            return self._reading(*self.world.finger_status())
        self._pending = command
        snapshot = self._snapshot
        if snapshot is None or snapshot[0] != command:
            width = snapshot[1].width_m if snapshot is not None else width_m
            return FingerReading(width, False, self.MOVING_CURRENT_A)
        return snapshot[1]

    def apply_command(self) -> None:
        """Runner thread: hand the emulator's latest command to the world."""
        pending = self._pending
        if pending is not None:
            self.world.command_fingers(*pending)
            self._applied = pending

    def take_reading(self) -> None:
        """Runner thread: the reading `advance` answers with until the next one, tagged
        with the command the world ran. (Tagged with the latest *pending* one, a command
        that arrived between apply and read got the previous command's reading: an open
        right after a grip read as "stopped on an object while opening" at once.)"""
        self._snapshot = (self._applied, self._reading(*self.world.finger_status()))

    def idle_for_s(self) -> float:
        """Wall seconds since the emulator last drove the fingers (inf: never)."""
        return np.inf if self.last_call_wall_s is None else time.monotonic() - self.last_call_wall_s


class RealTimeRunner:
    """Steps a SimWorld in its own thread, paced to the wall clock (never faster than
    `real_time_rate`; slower when the physics cannot keep up). While nothing moves (no arm
    motion, fingers idle, every body slower than 1 mm/s) it does not step, so an idle
    scene costs no CPU (a held object at rest included). If the emulator stops driving the fingers (rGTO = 0, a fault) for
    `finger_idle_hold_s`, the fingers are stopped where they are."""

    CHUNK_S = 0.006  # simulated per lock hold (3 steps at 2 ms, ~6-15 ms of wall time)
    YIELD_S = 0.001

    def __init__(self, world: SimWorld, finger_plant: SimFingerPlant | None = None,
                 real_time_rate: float = 1.0, finger_idle_hold_s: float = 0.1):
        self.world, self.finger_plant = world, finger_plant
        self.real_time_rate = real_time_rate
        self.finger_idle_hold_s = finger_idle_hold_s
        self._stop = threading.Event()
        self._thread = None
        self.sim_s = 0.0  # simulated seconds stepped by this runner
        self.wall_busy_s = 0.0  # wall seconds spent stepping
        self.error = None

    def start(self) -> "RealTimeRunner":
        self._thread = threading.Thread(target=self._run, name="sim-world", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def real_time_factor(self) -> float:
        """Simulated seconds per wall second while stepping."""
        return self.sim_s / self.wall_busy_s if self.wall_busy_s > 0 else float("nan")

    def _run(self):
        sim_wall_offset = None
        try:
            while not self._stop.is_set():
                fp = self.finger_plant
                with self.world.lock:
                    if fp is not None:
                        if fp.idle_for_s() < self.finger_idle_hold_s:
                            fp.apply_command()
                        elif self.world.fingers_commanded():
                            self.world.hold_fingers()
                    busy = self.world.needs_stepping()
                    if busy:
                        t0 = time.monotonic()
                        self.world.advance(self.CHUNK_S)
                        self.wall_busy_s += time.monotonic() - t0
                        self.sim_s += self.CHUNK_S
                    if fp is not None:
                        fp.take_reading()
                if not busy:
                    sim_wall_offset = None
                    self._stop.wait(self.CHUNK_S)
                    continue
                # Let waiting threads (services, the publisher) take the lock: a released
                # lock is not handed over, and re-taking it at once starved them.
                time.sleep(self.YIELD_S)
                # pace: sim time since the busy period began must not run ahead of wall time
                now = time.monotonic()
                if sim_wall_offset is None:
                    sim_wall_offset = (now, self.sim_s)
                ahead = (self.sim_s - sim_wall_offset[1]) / self.real_time_rate - (now - sim_wall_offset[0])
                if ahead > 0:
                    self._stop.wait(ahead)
        except Exception as e:  # reported by the node; the world is left as it was
            self.error = e
