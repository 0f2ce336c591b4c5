"""`run_node`: how every node process of the project starts, spins and shuts down.

It lives in the lowest Python package so that every package's nodes share it (the
dependencies point one way: robotiq_driver <- gravgrasp_detector <- sim_bridge).

A node's `main` is one line, e.g. `return run_node("tsdf", TSDFNode, InputError)`
(`spin` alone for a process that builds several nodes itself, as `stack` does):
a start-up error in the node's constructor (bad parameter, missing model file) prints one
line, "[FATAL] [<node>]: cannot start: <why>", and the process exits 2; Ctrl-C and an
external shutdown end it with 0 after `node.close()` (if the node has one).
"""

from __future__ import annotations

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor


def run_node(name: str, make_node, start_errors=(ValueError,), threads: int | None = None, args=None) -> int:
    """rclpy.init, `make_node()`, spin until Ctrl-C or shutdown, clean up; -> exit code.

    `start_errors`: the exceptions the constructor raises for a bad configuration; they
    end the process with one line and code 2 (anything else is a bug: traceback).
    `threads`: None spins a single-threaded executor, else a MultiThreadedExecutor.
    """
    rclpy.init(args=args)
    try:
        node = make_node()
    except start_errors as err:
        rclpy.logging.get_logger(name).fatal(f"cannot start: {err}")
        rclpy.try_shutdown()
        return 2
    return spin([node], threads)


def spin(nodes, threads: int | None = None) -> int:
    """Spin `nodes` (rclpy already initialised) until Ctrl-C or shutdown, then
    `shut_down(nodes)`; -> 0."""
    executor = SingleThreadedExecutor() if threads is None else MultiThreadedExecutor(num_threads=threads)
    for node in nodes:
        executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        shut_down(nodes)
    return 0


def shut_down(nodes) -> None:
    """`close()` each node that has one, destroy them and shut rclpy down (also for a
    process that fails to start after building some of its nodes)."""
    for node in nodes:
        if hasattr(node, "close"):
            node.close()
        node.destroy_node()
    rclpy.try_shutdown()
