"""Run independent tasks on a `concurrent.futures.Executor`.

Local runs use a process pool (spawned workers: each Drake simulation uses one
core, and spawning keeps workers free of the parent's threads); with a Dask
scheduler address the same tasks run on a cluster through
`distributed.Client(address).get_executor()`.  Task functions must be
module-level (picklable) and must not depend on execution order: every task
derives its random seed from the master seed and its own id (`task_seed`).
Results come back to this process, which alone writes the outputs.
"""

import concurrent.futures as cf
import contextlib
import ctypes
import hashlib
import multiprocessing
import os
import signal
import sys

from tqdm import tqdm


def task_seed(master_seed, *task_id):
    """A 63-bit seed from the master seed and a task id (str/int parts), stable
    across processes, machines and Python versions (no hash randomization)."""
    text = "\x1f".join(str(p) for p in (master_seed,) + task_id)
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little") >> 1


def _init_worker():
    # one core per simulation; keep BLAS/OpenMP from oversubscribing
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    _die_with_parent()


def _die_with_parent():
    """Linux: SIGTERM this worker when the process that started it dies. A killed
    `datagen` (kill, a closed terminal, a session's end) otherwise left its pool workers
    simulating for nobody, holding the cores, for hours."""
    if not sys.platform.startswith("linux"):
        return
    PR_SET_PDEATHSIG = 1
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() == 1:  # the parent died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)


@contextlib.contextmanager
def make_executor(workers=None, scheduler=None):
    """Executor for `workers` local processes, or a Dask cluster at `scheduler`
    (e.g. "tcp://10.0.0.1:8786"; the workers need this package and the data paths)."""
    if scheduler:
        import distributed  # lazy: Dask (a second to import) only for a cluster run

        with distributed.Client(scheduler) as client:
            with client.get_executor() as executor:
                yield executor
        return
    workers = workers or os.cpu_count() or 1
    with cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                initializer=_init_worker) as executor:
        yield executor


def run_tasks(executor, fn, tasks, on_result, desc="tasks", progress=True):
    """Submit fn(task) for every task; call on_result(task, result) here as each
    finishes (in completion order; outputs must not depend on it).
    Returns the number of tasks run."""
    tasks = list(tasks)
    futures = {executor.submit(fn, t): t for t in tasks}
    with tqdm(total=len(tasks), desc=desc, disable=not progress, unit="task", dynamic_ncols=True) as bar:
        try:
            for fut in cf.as_completed(futures):
                on_result(futures[fut], fut.result())
                bar.update(1)
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
    return len(tasks)
