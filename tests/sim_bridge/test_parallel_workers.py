"""Local pool workers die with the process that started them (a killed datagen must not
leave simulations running for nobody)."""
import os
import signal
import subprocess
import sys
import textwrap
import time

PARENT = textwrap.dedent("""
    import os, sys, time
    from sim_bridge.parallel import make_executor

    with make_executor(workers=1) as ex:
        print(ex.submit(os.getpid).result(), flush=True)
        ex.submit(time.sleep, 600)
        time.sleep(600)
""")


def alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie is dead too
        return f.read().split()[2] != "Z"


def test_killing_the_parent_ends_its_pool_workers():
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    worker = int(parent.stdout.readline())
    assert alive(worker)
    parent.send_signal(signal.SIGKILL)  # no cleanup code runs in the parent
    parent.wait()
    deadline = time.monotonic() + 10
    while alive(worker) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not alive(worker), "pool worker outlived its killed parent"
