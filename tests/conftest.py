"""Shared fixtures. Tests run from a shell that sourced ros_ws/env.sh (make test does).

Layout: tests/<package>/ for each package's tests, tests/system/ for the cross-package
tests (end to end, and the import rules), tests/support/ for helpers (importable by name from any test),
tests/data/ for recorded data. Markers (pytest.ini): `ros` is added here to every test
that starts ROS nodes or a DDS participant (the ros_node / ros_process fixtures);
modules that run Drake simulations mark themselves `drake`, tests that train a network
`slow`. The quick subset:
    python -m pytest -m "not ros and not drake and not slow and not soak"
"""
import collections
import os
import pathlib
import sys

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).with_name("support")))

import ros_testing  # noqa: E402  (from tests/support, put on the path above)

# One ROS domain for this whole pytest run, claimed before anything starts rclpy, so
# both this process and the nodes it spawns use it and other runs never cross-talk.
_DOMAIN = ros_testing.claim_domain_id()
os.environ["ROS_DOMAIN_ID"] = str(_DOMAIN)
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
# `make test` runs three pytest workers on a 2-core machine (pytest-xdist): one math
# thread per process (this one and the nodes it starts) instead of several each fighting
# over the same cores.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("OMP_NUM_THREADS", "1")


HEAVY_MARKERS = ("ros", "drake", "slow", "soak")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if {"ros_node", "ros_process"} & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.ros)
    # Heavy files first, each kept whole and in order: those with the most kinds of heavy
    # work (ROS processes and Drake: the end-to-end tests, the soak), then the rest of
    # the heavy ones, the quick files last. `make test`'s workers take whole files
    # in this order (with --no-loadscope-reorder: xdist's default re-sorts files by test count,
    # one-test heavy files last), so the quick files fill the gaps at the end instead of one worker
    # running the end-to-end tests alone.
    weight = collections.Counter()
    for item in items:
        marks = {m for m in HEAVY_MARKERS if item.get_closest_marker(m)}
        weight[item.path] = max(weight[item.path], len(marks))
    items.sort(key=lambda item: -weight[item.path])


def pytest_report_header(config):
    return f"ROS_DOMAIN_ID={_DOMAIN}"


def pytest_unconfigure(config):
    ros_testing.release_domain_id(_DOMAIN)


@pytest.fixture
def ros_node(request):
    """An rclpy node in the default context (so rclpy.spin_once works on it),
    initialised for this test and shut down after it."""
    import re

    import rclpy

    rclpy.init()
    node = rclpy.create_node("test_" + re.sub(r"\W", "_", request.node.name)[:40])
    yield node
    node.destroy_node()
    rclpy.try_shutdown()


@pytest.fixture
def ros_process(tmp_path):
    """Factory: ros_process(pkg, exe, args=(), params={}, remap={}) -> running RosProcess.

    Every process is stopped after the test, and the test fails if one survives."""
    started = []

    def start(package, name, args=(), params=None, remap=None, env=None, cmd=None):
        proc = ros_testing.RosProcess(package, name, args, params, remap, env, log_dir=tmp_path, cmd=cmd)
        started.append(proc)
        return proc

    yield start
    for proc in started:
        proc.stop()
    leftovers = [p.name for p in started if p.group_alive()]
    assert not leftovers, f"processes left behind: {leftovers}"
