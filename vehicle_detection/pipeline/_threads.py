"""Thread counts of a worker process, set before numba is loaded in it.

A spawned worker imports this module to run its initializer before it unpickles its first task
(which loads the detector, and numba with it), so this module imports nothing heavy.
"""

from __future__ import annotations

import os
import signal
import sys

__all__ = ["init_worker", "set_numba_threads"]


def init_worker(threads: int) -> None:
    """Start of a worker process: numba's threads, and Ctrl-C and SIGTERM ignored between tasks.

    The parent stops a running task with SIGTERM (the task cleans up and returns); between
    tasks the worker ignores both, so that it ends only when the pool is shut down.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    set_numba_threads(threads)


def set_numba_threads(n: int) -> None:
    """numba's threads: its pool's size when numba is not loaded yet, and the threads it uses."""
    if "numba" not in sys.modules:
        os.environ["NUMBA_NUM_THREADS"] = str(n)  # numba's thread pool size, read when it loads
    import numba  # after NUMBA_NUM_THREADS is set: the reason this module exists

    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
