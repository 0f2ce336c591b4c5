"""The demo's wait for a fresh view after a TSDF reset (clutter_demo.wait_for_fresh_grasps):
a slow camera still gives the fresh grasps, a stalled one ends the round as a stalled view
naming the frames it sent, never as "no grasp detected"; a grasps message that came
between two checks is not missed."""
import threading
import time
import types

import pytest

from sim_bridge.benchmark.clearing import Stalled, clear_table
from sim_bridge.ros.clutter_demo import FRESH_AFTER_RESET_S, wait_for_fresh_grasps

T_RESET_NS = 10**12


def grasps_at(t_s, n=1):
    sec, frac = divmod(T_RESET_NS + int(t_s * 1e9), 10**9)
    return types.SimpleNamespace(header=types.SimpleNamespace(stamp=types.SimpleNamespace(sec=sec, nanosec=frac)),
                                 grasps=[object()] * n)


class Camera:
    """Depth frames every `period_s` until `stops_after` frames; the detector publishes
    grasps for the volume of each frame, stamped at the frame's time after the reset."""

    def __init__(self, period_s, stops_after=None):
        self.latest, self.frames, self.arrived = None, 0, threading.Event()
        self.period_s, self.stops_after = period_s, stops_after
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self):
        t0 = time.monotonic()
        while self.stops_after is None or self.frames < self.stops_after:
            time.sleep(self.period_s)
            self.frames += 1
            self.latest = grasps_at(time.monotonic() - t0)
            self.arrived.set()


def wait(camera, timeout_s):
    return wait_for_fresh_grasps(lambda: camera.latest, camera.arrived, lambda: camera.frames, T_RESET_NS, timeout_s,
                                 poll_s=0.05)


def test_a_slow_camera_still_gives_the_first_fresh_view():
    camera = Camera(period_s=0.4)  # 2.5 Hz on a busy machine, not the sim's 4
    g = wait(camera, timeout_s=5)
    t = (g.header.stamp.sec * 10**9 + g.header.stamp.nanosec - T_RESET_NS) / 1e9
    assert FRESH_AFTER_RESET_S < t < FRESH_AFTER_RESET_S + 1.0 and camera.frames >= 2


def test_a_stalled_camera_ends_the_wait_naming_its_frames():
    camera = Camera(period_s=0.1, stops_after=1)  # one frame just after the reset, then nothing
    with pytest.raises(Stalled, match=r"the camera stalled \(1 depth frame since the reset\)"):
        wait(camera, timeout_s=1.0)


def test_frames_without_a_fresh_volume_name_the_tsdf_or_detector():
    with pytest.raises(Stalled, match=r"the TSDF or the detector stalled \(7 depth frames since the reset\)"):
        wait_for_fresh_grasps(lambda: grasps_at(0.1), threading.Event(), lambda: 7, T_RESET_NS, 0.3, poll_s=0.05)


def test_a_fresh_view_that_came_before_the_wait_is_not_missed():
    arrived = threading.Event()  # already cleared: its message came before the wait began
    g = grasps_at(FRESH_AFTER_RESET_S + 0.2)
    t0 = time.monotonic()
    assert wait_for_fresh_grasps(lambda: g, arrived, lambda: 3, T_RESET_NS, 10) is g
    assert time.monotonic() - t0 < 0.1


def test_a_stalled_view_ends_the_round_as_that_not_as_nothing_detected():
    class Cell:
        def objects_on_table(self):
            return ["a", "b"]

        def detect(self):
            raise Stalled("no view after the TSDF reset within 60 s: the camera stalled (1 depth frame since the reset)")

    record = clear_table(Cell(), 2)
    assert record["end"] == "view_stalled" and "1 depth frame" in record["stalled"] and record["attempts"] == []
