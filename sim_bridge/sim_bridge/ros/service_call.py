"""A blocking ROS service call for code whose node a background executor spins (the demo,
the soak run, the system tests' `BackgroundSpin`): wait for the service, send the
request, wait on the answer's future. Only the caller's thread blocks; the executor's
threads deliver the answer. No rclpy import: it works on any client."""
from __future__ import annotations

import threading


class ServiceTimeout(TimeoutError):
    """The service is not there, or it did not answer in time."""


def call_blocking(client, request, timeout_s: float, wait_for_service_s: float = 30.0):
    """`client`'s response to `request`; raises ServiceTimeout when the service does not
    appear within min(timeout_s, wait_for_service_s) or does not answer within timeout_s.
    The node that owns `client` must be spun by another thread (a MultiThreadedExecutor),
    or the answer never arrives."""
    name = client.srv_name
    if not client.wait_for_service(timeout_sec=min(timeout_s, wait_for_service_s)):
        raise ServiceTimeout(f"service {name} is not available (is its node running?)")
    done = threading.Event()
    future = client.call_async(request)
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout_s):
        raise ServiceTimeout(f"service {name} did not answer in {timeout_s:g} s")
    return future.result()
