"""Reloading the sim bridge's scene (`load_scene` -> SimWorld.reset) must not grow memory.

Before the fix every reset left its whole Drake diagram behind (pydrake never freed a
diagram holding a Python LeafSystem): +15-19 MB of RSS per reset, +33 % over a 10 min
soak; freed, it still stayed in the malloc arena of the thread that reloaded. Measured
as the sim node does it (reset on a new thread, render a frame, step), in a fresh
interpreter: inside the test run's process the heap of 300 earlier tests made the RSS
figure drift by tens of MB with no diagram kept.
"""
import ctypes
import gc
import json
import os
import pathlib
import subprocess
import sys
import threading

import pytest

from sim_bridge.world import SceneConfig, SimFingerPlant, SimWorld, WorldSettings

pytestmark = pytest.mark.drake

WARM_UP_RESETS = 3  # the allocator settles (the first rebuilds reserve arenas)
MEASURED_RESETS = 6
# RSS after each measured reload; mean of the last 3 minus mean of the first 3. Leaking
# ~15 MB per reload that is ~45 MB; flat, within +-10 MB of allocator noise.
MAX_RSS_GROWTH_MB = 20.0


def rss_mb():
    """Resident memory after gc and a malloc trim: what is live, not what the allocator keeps."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    for line in pathlib.Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError("no VmRSS in /proc/self/status")


def live_diagrams():
    gc.collect()
    return sum(1 for o in gc.get_objects() if type(o).__name__ == "Diagram")


def reload(world, seed):
    """On a new thread each time, as the sim node's executor threads serve load_scene
    (each thread allocates from its own malloc arena)."""
    def work():
        world.reset(SceneConfig(seed=seed, n_objects=3))
        world.render_depth()
        world.advance(0.02)
    thread = threading.Thread(target=work)
    thread.start()
    thread.join()


def measure():
    """In this (fresh) process: RSS after each measured reload, diagrams alive before and
    after, and whether the world in use still closes its fingers; one JSON line."""
    world = SimWorld(SceneConfig(seed=1, n_objects=3), WorldSettings())
    diagrams_before = live_diagrams()
    for i in range(WARM_UP_RESETS):
        reload(world, seed=1 + i % 2)
    rss = []
    for i in range(MEASURED_RESETS):
        reload(world, seed=1 + i % 2)
        rss.append(rss_mb())
    diagrams_after = live_diagrams()
    plant = SimFingerPlant(world)
    width = world.finger_width_m()
    for _ in range(200):
        reading = plant.advance(0.01, width, 0.0, 0.1, 40.0)
        width = reading.width_m
        if reading.current_a == 0.0:
            break
    print(json.dumps(dict(rss=rss, diagrams_before=diagrams_before, diagrams_after=diagrams_after,
                          closed=bool(reading.current_a == 0.0 and width < 0.005), reading=str(reading))))


def test_repeated_scene_reloads_free_the_previous_world():
    run = subprocess.run([sys.executable, __file__], capture_output=True, text=True, timeout=280, env=os.environ)
    assert run.returncode == 0, run.stderr[-3000:]
    r = json.loads(run.stdout.strip().splitlines()[-1])
    rss = r["rss"]
    growth_mb = sum(rss[-3:]) / 3 - sum(rss[:3]) / 3
    print(f"rss_mb={[round(v, 1) for v in rss]} growth_mb={growth_mb:.1f}")

    # every replaced diagram is gone: the same number alive as before the resets
    assert r["diagrams_after"] == r["diagrams_before"]
    assert growth_mb < MAX_RSS_GROWTH_MB, (
        f"RSS after each of {MEASURED_RESETS} scene reloads {[round(v) for v in rss]} MB: grew "
        f"{growth_mb:.1f} MB in 3 reloads; the previous worlds are kept alive")
    # the world in use still works after its predecessors were freed: fingers close
    assert r["closed"], r["reading"]


if __name__ == "__main__":
    measure()
