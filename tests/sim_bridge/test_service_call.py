"""call_blocking against a client that loses the reply to its first request, as a
server does when it has not yet discovered a just-created client (rmw_fastrtps#842)."""
import threading

import pytest
from sim_bridge.ros.service_call import ServiceTimeout, call_blocking


class Future:
    def __init__(self):
        self._done, self._result, self._callbacks = False, None, []

    def add_done_callback(self, callback):
        self._callbacks.append(callback)
        if self._done:
            callback(self)

    def set_result(self, result):
        self._done, self._result = True, result
        for callback in self._callbacks:
            callback(self)

    def done(self):
        return self._done

    def result(self):
        return self._result


class ClientThatLosesTheFirstReply:
    srv_name = "/lossy"

    def __init__(self):
        self.requests = []

    def wait_for_service(self, timeout_sec):
        return True

    def call_async(self, request):
        self.requests.append(request)
        future = Future()
        if len(self.requests) > 1:  # answered from another thread, as an executor would
            threading.Timer(0.05, future.set_result, args=(f"reply to {request}",)).start()
        return future


def test_a_resent_request_gets_the_reply_the_first_lost():
    client = ClientThatLosesTheFirstReply()
    assert call_blocking(client, "disarm", timeout_s=5.0, resend_s=0.2) == "reply to disarm"
    assert client.requests == ["disarm", "disarm"]


def test_without_resend_a_lost_reply_is_a_timeout_that_says_how_many_were_sent():
    client = ClientThatLosesTheFirstReply()
    with pytest.raises(ServiceTimeout, match=r"/lossy did not answer in 0.3 s \(1 request\(s\) sent\)"):
        call_blocking(client, "execute", timeout_s=0.3)
    assert client.requests == ["execute"]
