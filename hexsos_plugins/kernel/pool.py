"""The kernel's threads: its chunk functions release the GIL, so cells run in parallel on Python threads of one
pool; each task owns its scratch arrays and nothing is pickled; a small call runs in the calling thread at once.

Owns: the thread count (:func:`set_threads`, :func:`threads`), :func:`spread`, :func:`run_all`. Imports nothing of
hexsos.
"""

from __future__ import annotations

import os
import threading
from contextlib import contextmanager
from concurrent.futures import ThreadPoolExecutor

__all__ = ["cores", "set_threads", "threads", "threads_for", "spread", "run_all", "last_threads", "CHUNK",
           "LIGHT_CHUNK"]

CHUNK = 4096  # cells per task on a thread (each task allocates its scratch once)
_THREADS = 1  # threads the kernel may use (set_threads); chunks of CHUNK cells are spread over them
LIGHT_CHUNK = 32768  # cells per task of a pass of a few nanoseconds a cell (the verdicts): ~0.3 ms of work
_POOL = None
#: The Python threads that have run the kernel's chunks since this was last reset to an empty set (for tests and
#: benchmarks: a light pass's short tasks may all go to one thread, so one call alone proves little).
last_threads: set = set()


def cores() -> int:
    """The cores this process may run on (its CPU affinity, which a container or ``taskset`` narrows)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


def threads() -> int:
    """The number of threads the kernel may use now."""
    return _THREADS


def set_threads(n: int) -> int:
    """Let the kernel use n threads (its chunk functions release the GIL); returns the previous setting."""
    global _THREADS
    old, _THREADS = _THREADS, max(1, int(n))
    return old


def _pool():
    global _POOL
    if _POOL is None or _POOL._max_workers != _THREADS:
        _POOL = ThreadPoolExecutor(max_workers=_THREADS, thread_name_prefix="hexsos-kernel")
    return _POOL


def run_all(calls):
    """The results of ``calls`` (callables of no argument, each writing only to its own arrays), in their order:
    on the pool's threads when the kernel may use more than one (functions that release the GIL run at once), else
    one after the other in the calling thread. The work is the same either way, so the results are too."""
    if _THREADS <= 1 or len(calls) <= 1:
        return [c() for c in calls]
    seen = set()

    def task(c):
        seen.add(threading.get_ident())
        return c()

    futures = [_pool().submit(task, c) for c in calls]
    out = [f.result() for f in futures]
    last_threads.update(seen)
    return out


def spread(fn, n_ids, args_of, min_chunk=CHUNK):
    """fn(*args_of(start, stop)) over chunks of cells: inline for one thread or a small input, else on a pool,
    each task at least ``min_chunk`` cells (more for a light pass, whose cells take nanoseconds)."""
    if _THREADS <= 1 or n_ids <= min_chunk:
        fn(*args_of(0, n_ids))
        return
    # about four chunks per thread keeps them busy without many tiny tasks
    size = max(min_chunk, -(-n_ids // (4 * _THREADS)))
    seen = set()

    def task(start, stop):
        seen.add(threading.get_ident())
        fn(*args_of(start, stop))

    pool = _pool()
    futures = [pool.submit(task, s, min(s + size, n_ids)) for s in range(0, n_ids, size)]
    for f in futures:
        f.result()
    last_threads.update(seen)



@contextmanager
def threads_for(jobs):
    """The kernel's thread count inside the block (restored afterwards); 0: one per core."""
    want = cores() if jobs == 0 else max(1, int(jobs))
    old = set_threads(want)
    try:
        yield want
    finally:
        set_threads(old)
