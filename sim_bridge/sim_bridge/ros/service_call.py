"""A blocking ROS service call for code whose node a background executor spins (the demo,
the soak run, the system tests' `BackgroundSpin`): wait for the service, send the
request, wait on the answer's future. Only the caller's thread blocks; the executor's
threads deliver the answer. No rclpy import: it works on any client."""
from __future__ import annotations

import threading
import time


class ServiceTimeout(TimeoutError):
    """The service is not there, or it did not answer in time."""


def call_blocking(client, request, timeout_s: float, wait_for_service_s: float = 30.0,
                  resend_s: float | None = None):
    """`client`'s response to `request`; raises ServiceTimeout when the service does not
    appear within min(timeout_s, wait_for_service_s) or does not answer within timeout_s.
    The node that owns `client` must be spun by another thread (a MultiThreadedExecutor),
    or the answer never arrives.

    A server drops its reply when it has not yet discovered a just-created client's reply
    reader (rmw_fastrtps waits 100 ms; ros2/rmw_fastrtps#842), which happens on a loaded
    machine. `resend_s`, only for requests that are safe to repeat, sends the request again
    after that long without an answer; the first answer to any of them is returned."""
    name = client.srv_name
    if not client.wait_for_service(timeout_sec=min(timeout_s, wait_for_service_s)):
        raise ServiceTimeout(f"service {name} is not available (is its node running?)")
    done = threading.Event()
    deadline = time.monotonic() + timeout_s
    futures = []
    while True:
        futures.append(client.call_async(request))
        futures[-1].add_done_callback(lambda _: done.set())
        left = deadline - time.monotonic()
        if done.wait(left if resend_s is None else min(resend_s, left)):
            return next(f for f in futures if f.done()).result()
        if time.monotonic() >= deadline:
            raise ServiceTimeout(f"service {name} did not answer in {timeout_s:g} s ({len(futures)} request(s) sent)")
